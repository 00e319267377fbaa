"""The paper's Fig. 2 from the committed runs, ours beside the authors': `python -m
studies.fig2` is `hercs plot --figure 2 docs/results/runs/*/` writing docs/results/fig2.png
and its tables, docs/results/fig2.md (what `make figures` runs).
"""
