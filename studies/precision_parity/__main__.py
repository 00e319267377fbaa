"""`python -m studies.precision_parity`: the study's runner
(studies/precision_parity/precision_band.py)."""

from studies.precision_parity.precision_band import main

raise SystemExit(main())
