"""5. Replay memory: the replay's own RSS growth holding the full buffer against the bytes of
the store's arrays."""

from __future__ import annotations

from bench.perf.throughput.harness import Harness
from bench.perf.throughput.plan import SEED
from bench.perf.throughput.throughput_report import Figure, Target
from bench.synthetic_episodes import random_episode
from hercs.replay_service.store import EpisodeStore
from hercs.rl.seeding import generator
from hercs.rl.task_registry import TaskSpec

STORE_COLUMNS = ("obs", "ag", "g", "actions", "episode_id", "actor_id", "seq", "success",
                 "final_ag", "energy", "cluster", "policy_version")
"""The store's per-episode arrays (public views of `EpisodeStore`), for the raw byte count."""


def store_bytes_per_episode(spec: TaskSpec) -> int:
    """Bytes of one episode in the store's arrays (`STORE_COLUMNS`; the object column of actor
    ids counts its 8-byte pointers, not the strings)."""
    store = EpisodeStore(capacity_episodes=1, spec=spec)
    store.insert(random_episode(spec, generator(SEED, "bench", "bytes")))
    return int(sum(getattr(store, name).nbytes for name in STORE_COLUMNS))


def own_rss_mib(memory: dict[str, float]) -> float:
    """VmRSS without RssShmem: the pages this process owns.

    Zenoh 1.x enables its shared-memory transport optimisation by default: every local session
    that sends messages above 3 KiB (Episodes, Batches) allocates a 16 MiB pool, and a receiver
    maps the senders' pools, so the replay's VmRSS grew by up to 16 MiB per local peer that
    ever sent it a large message — pages owned and counted by the sender too, independent of
    what the replay stores. Our sessions now turn it off (hercs/net/transport.py), so RssShmem
    should be ~0; it stays subtracted in case a deployment turns it back on.
    """
    return memory["VmRSS"] - memory["RssShmem"]



def figures(bench: Harness, *, idle: dict[str, float], filled: dict[str, float],
                   episodes: int) -> None:
    per_episode = store_bytes_per_episode(bench.spec)
    raw_mib = per_episode * episodes / 2**20
    growth_mib = own_rss_mib(filled) - own_rss_mib(idle)
    total_mib = filled["VmRSS"]
    transitions = episodes * bench.spec.episode_steps
    bench.details["memory"] = {
        "idle_mib": idle, "filled_mib": filled, "raw_bytes_per_episode": per_episode,
        "stored_episodes": episodes, "raw_mib": raw_mib,
        "own_rss_growth_mib": growth_mib}
    bench.figures.append(Figure(
        key="replay_rss_growth", name="replay RSS growth", unit="MiB",
        ours=growth_mib, reference=raw_mib,
        ours_what=f"VmRSS − RssShmem of the replay holding {transitions:,} transitions "
                  "after serving the sample requests, minus the same when it had just "
                  "started (empty store); RssShmem = the Zenoh shared-memory pools of the "
                  "local senders, mapped by the replay",
        reference_what=f"bytes of the store's arrays for {episodes:,} episodes "
                       f"({per_episode:,} B each: obs, ag, g, actions, metadata)",
        target=Target("ratio_at_most", 1.5)))
    bench.figures.append(Figure(
        key="replay_rss_total", name="replay RSS total", unit="MiB",
        ours=total_mib, reference=raw_mib,
        ours_what=f"VmRSS of the replay holding {transitions:,} transitions, nothing "
                  "subtracted (interpreter, libraries, Zenoh shared-memory pools "
                  f"{filled['RssShmem']:.0f} MiB included)",
        reference_what="bytes of the store's arrays, as above"))
