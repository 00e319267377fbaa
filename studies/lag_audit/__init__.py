"""Which committed runs recorded a shifted policy lag after a resume (issue 45's bug), and
what lag they really trained at: `python -m studies.lag_audit`."""
