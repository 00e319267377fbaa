"""An actor's metrics row (`hercs up`'s progress, TensorBoard), from its inserter's counters."""

from __future__ import annotations

from hercs.actors.inserter import InsertCounters


def unacked(episodes: int, counters: InsertCounters) -> int:
    """Episodes submitted and not acked, dropped or superseded: queued, in flight or given
    up."""
    return episodes - counters.acked - counters.dropped - counters.superseded


def actor_metrics(counters: InsertCounters, *, env_steps: int, episodes: int,
                  steps_per_s: float, policy_version: int,
                  weights_rejected: int) -> dict[str, float]:
    c = counters
    return {
        "env_steps": env_steps,
        "episodes": episodes,
        "env_steps_per_s": steps_per_s,
        "acked": c.acked,
        "retries": c.retries,
        "dropped": c.dropped,
        "superseded": c.superseded,
        "unacked": unacked(episodes, c),
        "duplicates": c.duplicates,
        "insert_blocked_s": c.blocked_s,
        "policy_version": policy_version,
        "weights_rejected": weights_rejected,
    }
