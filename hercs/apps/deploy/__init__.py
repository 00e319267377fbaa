"""A run beyond one host: its certificates and its Slurm job."""
