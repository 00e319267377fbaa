"""Actors: rollout workers (exploring) and the evaluator (deterministic test episodes)."""
