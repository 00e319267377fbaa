"""`python -m studies.fig2`: the study's runner (studies/fig2/paper_figure.py)."""

from studies.fig2.paper_figure import main

raise SystemExit(main())
