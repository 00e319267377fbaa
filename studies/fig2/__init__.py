"""The paper's Fig. 2 from the committed runs, ours beside the authors': `python -m
studies.fig2` draws docs/results/fig2.png and writes its tables, docs/results/fig2.md, with
hercs' `hercs plot --figure 2` and the studies' styling (studies/legacy_runs.py).
"""
