"""3. Inserts/s acked from 1, 2, 4, 8, 16 concurrent synthetic actors, and the largest
levels again into a replay that draws no Foxglove scenes."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from bench.perf.throughput import BenchError, say
from bench.perf.throughput.harness import Child, Harness
from bench.perf.throughput.plan import NO_SCENE
from bench.perf.throughput.rates import percentile
from bench.perf.throughput.throughput_report import Figure, Target


def insert_rates(bench: Harness, replay: Child, counts: Sequence[int], *, label: str = ""
                 ) -> dict[str, Any]:
    """Per insert level: acked episodes/s (`episodes_per_s`), ack latency and the replay's
    CPU share (`ack_latency`), episodes per replay CPU-second; the phase's `details`."""
    p = bench.plan
    rates: dict[int, float] = {}
    per_cpu: dict[int, float] = {}
    latency: dict[int, dict[str, float]] = {}
    for n in counts:
        with bench.fleet.running(n):
            time.sleep(p.insert_warmup_s)
            cpu0, opened = replay.cpu_seconds(), time.monotonic()
            time.sleep(p.insert_window_s)
            cpu1, closed = replay.cpu_seconds(), time.monotonic()
        acks = bench.fleet.acks_between(opened, closed)
        if not acks:
            raise BenchError(f"no insert acked in {p.insert_window_s:g} s with {n} actors")
        rates[n] = len(acks) / (closed - opened)
        per_cpu[n] = len(acks) / max(cpu1 - cpu0, 1e-9)
        lat_ms = [a[2] * 1e3 for a in acks]
        latency[n] = {"p50_ms": percentile(lat_ms, 50), "p99_ms": percentile(lat_ms, 99),
                      "replay_cpu_share": (cpu1 - cpu0) / (closed - opened)}
        say(f"inserts{label}, {n} synthetic actor(s): {rates[n]:.1f} episodes/s acked, "
            f"ack latency p50 {latency[n]['p50_ms']:.1f} ms, replay CPU "
            f"{latency[n]['replay_cpu_share']:.2f} → {per_cpu[n]:.0f} episodes per "
            "replay CPU-second")
    return {"episodes_per_s": rates, "ack_latency": latency,
            "episodes_per_replay_cpu_s": per_cpu, "window_s": p.insert_window_s}


def measure(bench: Harness, replay: Child) -> None:
    p = bench.plan
    details = bench.details["inserts"] = insert_rates(bench, replay, p.insert_actor_counts)
    rates, per_cpu, latency = (details["episodes_per_s"], details["episodes_per_replay_cpu_s"],
                               details["ack_latency"])
    base = rates[p.insert_actor_counts[0]]
    for n in p.insert_actor_counts:
        bench.figures.append(Figure(
            key=f"inserts_per_s_{n}_actors", name=f"inserts/s acked, {n} actor(s)",
            unit="episodes/s", ours=rates[n], reference=base,
            ours_what=f"{n} concurrent synthetic actor(s), each with its own Zenoh session "
                      f"and one Push episode in flight, acked episodes per second (the "
                      f"replay used {latency[n]['replay_cpu_share']:.2f} CPU: "
                      f"{per_cpu[n]:.0f} episodes per replay CPU-second)",
            reference_what=f"the same with {p.insert_actor_counts[0]} actor (ratio = "
                           "speed-up)",
            target=Target("ours_at_least", 1000.0) if n >= 8 else None))


def measure_without_scenes(bench: Harness) -> None:
    """The largest insert levels again, into a fresh replay with `replay.log_scene=false`:
    what drawing each episode's Foxglove scene costs the replay (docs/PERFORMANCE.md §6)."""
    p = bench.plan
    replay = bench.start("replay", "bench-replay-no-scene", NO_SCENE)
    try:
        bench.status.clear()
        bench.wait_status(lambda s: True, what="the replay without scenes up", replay=replay)
        details = bench.details["inserts_no_scene"] = insert_rates(bench,
            replay, p.insert_no_scene_counts, label=" without scenes")
    finally:
        bench.stop(replay)
    rates, per_cpu, latency = (details["episodes_per_s"], details["episodes_per_replay_cpu_s"],
                               details["ack_latency"])
    with_scene = bench.details["inserts"]["episodes_per_s"]
    for n in p.insert_no_scene_counts:
        bench.figures.append(Figure(
            key=f"inserts_per_s_{n}_actors_no_scene",
            name=f"inserts/s acked, {n} actor(s), replay.log_scene=false",
            unit="episodes/s", ours=rates[n], reference=with_scene[n],
            ours_what=f"as above with {n} actor(s), into a replay of its own that logs "
                      "every episode but draws no Foxglove scene (the replay used "
                      f"{latency[n]['replay_cpu_share']:.2f} CPU: {per_cpu[n]:.0f} "
                      "episodes per replay CPU-second)",
            reference_what=f"the same {n} actor(s) into the replay drawing scenes, above "
                           "(ratio = what the scenes cost)",
            target=Target("ours_at_least", 1000.0) if n >= 8 else None))
