"""Rerun views of a run: offline from its log, live while it trains, on the web."""
