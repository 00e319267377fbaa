"""The product's benchmarks: scripts on top of hercs (nothing in the system imports them), each
run from the repository root as a module, `python -m bench.<package>.<name>`, writing into
docs/results/. `bench.perf` measures speed and size against physical limits, `bench.faults`
injects faults into real runs. The paper's questions are studies/, not here. What each one
measures is in its module docstring; docs/PERFORMANCE.md and docs/FAULTS.md collect the results.
"""
