"""`python -m studies.claims`: the study's runner (studies/claims/claims.py)."""

from studies.claims.claims import main

raise SystemExit(main())
