"""`hercs up`: the run's router and processes, their supervision, stall and resume."""
