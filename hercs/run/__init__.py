"""A run on disk: the run directory and its one owner (`RunDir`), the MCAP run log, metrics,
policy files and one-a-minute warnings."""
