"""The authors' published HER-CS code run on our Fetch*-v1 stack as a peer side, from a
checkout outside this repository (never copied in): `python -m studies.authors_peer`."""

PEER_SCHEDULE = "authors-code"
"""`training.schedule` of a peer run's config.yaml: its own group in the claims and Fig. 2
(here, so that they read it without importing the runner and its environments)."""
