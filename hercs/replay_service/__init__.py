"""Replay service: episode store, HER relabelling, energy, samplers (pure core, no transport)."""
