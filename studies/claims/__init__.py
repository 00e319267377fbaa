"""The project's claims as the field states them (IQM, bootstrap intervals, probability of
improvement over seeds) and how many seeds would show them: `python -m studies.claims` writes
docs/results/claims.md, `python -m studies.claims.seed_power` docs/results/seed_power.md.
"""
