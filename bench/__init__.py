"""The benchmarks: scripts on top of everything (nothing in the system imports them), each run
from the repository root as a module, `python -m bench.<name>`, writing into docs/results/.
What each one measures is in its module docstring; docs/PERFORMANCE.md collects the results.
"""
