"""The authors' published HER-CS code run on our Fetch*-v1 stack as a peer side, from a
checkout outside this repository (never copied in): `python -m studies.authors_peer`."""
