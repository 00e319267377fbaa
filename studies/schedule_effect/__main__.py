"""`python -m studies.schedule_effect`: the study's runner
(studies/schedule_effect/schedule_pairs.py)."""

from studies.schedule_effect.schedule_pairs import main

raise SystemExit(main())
