"""Throughput of the running system against its physical limits, measured side by side.

    python -m bench.perf.throughput  # full mode, ~5-10 min on 2 cores → docs/results/
    python -m bench.perf.throughput --quick  # CI mode: tiny sizes, well under a minute

One invocation (`__main__.py`) measures every figure below and writes `throughput.json` (every
figure, the raw measurements behind it, the machine, commit, date and command) and
`throughput.md` (a table: figure, ours, reference, ratio, target, verdict) to `--out`, and
prints the markdown. Targets are reported, never asserted: a noisy machine moves absolute
numbers, so each figure of the system ("ours") is paired with a reference measured in the same
run, for the two throughput pairs in short alternating slices (the system's process is paused
with SIGSTOP while the reference runs), and the ratio is what the target is about.

Figures (the system is real: an embedded Zenoh router on a free loopback port, and
`python -m hercs.apps.cli <role>` child processes connected to it):

1. **Env steps/s.** ours: one `hercs actor` (policy inference, exploration noise, acked
   inserts over Zenoh) counted at the replay — acked episodes × T per second from the
   `replay/inserted` headers. reference: raw FetchPush-v4 stepping with uniform random actions
   in this process. The two alternate in short slices (full mode: 12 actor slices of 2.5 s,
   each between two raw ones), so drifts of the background load hit both sides alike.
   Target ratio ≥ 0.9. Also per CPU-second of the actor process and of the stepping thread:
   the rates each would reach on a core of its own, free of the machine's load.
2. **Learner updates/s.** ours: the `hercs learner` process pulling 40×256 batches from the
   replay over Zenoh (its prefetcher overlaps sampling and transport with updates), counted
   from its `weights` broadcasts (one per cycle of `minibatches_per_cycle` updates).
   reference: the same `LearnerLoop.step` (DDPG updates, Polyak update) in this process, one
   torch thread as the service, on batches sampled beforehand from a local `ReplayCore`
   (sampling is outside the timed loop: the service's prefetch is meant to hide it);
   alternating slices as above (full mode: 8 of 4 s). Target ratio ≥ 0.95. Also per
   CPU-second of the learner process (all its threads) and of the updating thread.
3. **Insert throughput** with 1, 2, 4, 8, 16 concurrent synthetic actors (quick: 1, 2): each
   has its own Zenoh client session and one insert in flight, as `hercs.actors.inserter` delivers;
   episodes are pre-generated random Push episodes (`hercs.wire.episode.random_episode`). ratio =
   speed-up over one actor; target ≥ 1,000 acked episodes/s from 8 actors. At the end of the
   run the largest levels (8, 16; quick: 2) are measured again into a replay of its own with
   `replay.log_scene=false` (every episode logged, no Foxglove scene drawn), against the
   same level with scenes: what drawing the scenes costs the replay's one core.
4. **Sample latency** of a SampleRequest of 40 minibatches × 256 on a full buffer (1e6
   transitions = 20,000 Push episodes; quick: 500 episodes), for each sampler (`her`, `her-cs`,
   `her-ebp`, `her-ebp-cs`; quick: the first two): time from
   sending the request to holding the reply bytes, at a client of the router (the learner's
   path), decode excluded; per request and per minibatch (÷ 40). reference: `ReplayCore.sample`
   of the same size in this process on a store of the same size. Target p99 ≤ 1 ms per
   minibatch. The `her` replay is the one filled over Zenoh; the `her-cs` replay is the same
   run restarted with `run.method=her-cs`, refilled from its episode log (the replay's own
   crash recovery), and given a k=8 `ClusterModel` published on `cluster/model` as the
   clusterer would (its adoption is checked through `ReplayStatus.cluster_model_version`).
5. **Replay memory.** ours: VmRSS − RssShmem of the replay process holding 1e6 transitions,
   after serving the `her` sample requests, minus the same when it had just started (empty
   store: `np.zeros` commits no pages). RssShmem is Zenoh's shared-memory pools of the local
   senders, mapped by the replay (see `own_rss_mib`). reference: the bytes of the store's
   arrays at that size (per episode: obs, ag, g, actions and the per-episode metadata
   columns, the object column counted as pointers). Target ratio ≤ 1.5. The total VmRSS (no
   subtraction) is reported too.

The replay runs with `replay.free_run=true` throughout: there is no learner while the actor
is measured and no actor while the learner is, so the sample-to-insert rate limiter would
otherwise hold one side and the phase would measure the limiter, not the path.

One module per figure measured (`env_steps`, `learner_updates`, `insert_rate`,
`sample_latency`, `replay_memory`), on the system that `harness` starts; `report` writes the
result, `__main__` runs the phases in order.

Every child runs in its own process group and gets SIGKILL if this process dies
(PR_SET_PDEATHSIG); each phase stops its children with SIGTERM, then SIGKILL after a grace
period, in `finally` blocks.
"""

from __future__ import annotations

import sys
import time


class BenchError(RuntimeError):
    """A phase could not measure what it should (a child died, a wait timed out)."""


def say(text: str) -> None:
    """Progress on stderr (stdout carries the markdown report)."""
    print(f"[throughput {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)
