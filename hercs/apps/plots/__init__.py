"""`hercs plot`: learning curves, the paper's Fig. 2 layout and their tables."""
