"""The paper's questions, one package each, run from the repository root (never installed) as
`python -m studies.<package>`: each reads runs (committed under docs/results/runs/ or local),
computes its statistics and writes its findings to docs/results/*.md, the only place findings
live. Studies sit on top of hercs and beside bench/ (import-linter keeps them apart).
"""
