"""`hercs sweep`: grids of runs, resumable, locally or as a Slurm array, and reports."""
