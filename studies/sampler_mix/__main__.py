"""`python -m studies.sampler_mix`: the study's runner (studies/sampler_mix/sampler_draws.py)."""

from studies.sampler_mix.sampler_draws import main

raise SystemExit(main())
