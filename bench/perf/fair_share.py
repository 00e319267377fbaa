"""Each actor's share of the admitted inserts while one actor floods the replay, with fair
sharing off (arrival order) and on (round-robin across actor ids).

    python -m bench.perf.fair_share [--quick] [--out docs/results/fair_share]

Writes OUT.json and OUT.md; method and results: docs/PERFORMANCE.md §9."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import logging
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import REPO, git_commit, machine_identity
from bench.perf.throughput.harness import Child, Latest, free_endpoint
from bench.synthetic_episodes import random_episode
from hercs.actors.inserter import Inserter
from hercs.apps.launch.router import open_router
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.net.transport import Transport
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.rl.seeding import generator
from hercs.rl.task_registry import TaskSpec
from hercs.wire.codec import episode_to_msg

RUN = "fair-share"
TASK = "reach"
MINIBATCHES = 4
"""Per sample request; with ρ = 1 each request makes room for 4 inserts."""
FLOOD_SENDERS = 32
NORMAL_ACTORS = 3
MODES = {"arrival order (before)": 0, "round-robin (after)": 4}
"""Mode → `replay.waiting_inserts_per_actor`."""
READY_TIMEOUT_S = 120.0
SAMPLE_TIMEOUT_S = 30.0


@dataclasses.dataclass(frozen=True)
class Plan:
    capacity: float
    """Inserts per second the learner's stand-in makes room for."""
    normal_rate: float
    """Episodes per second each normal actor offers (an eighth of the capacity)."""
    warmup_s: float
    window_s: float


FULL = Plan(capacity=60.0, normal_rate=7.5, warmup_s=3.0, window_s=20.0)
QUICK = Plan(capacity=60.0, normal_rate=7.5, warmup_s=1.5, window_s=5.0)


def say(text: str) -> None:
    print(f"[fair_share {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


class Episodes:
    """Serialised synthetic Reach episodes under any (actor_id, seq), from a pool of 64."""

    def __init__(self, spec: TaskSpec) -> None:
        rng = generator(1, "bench", "fair-share")
        self._pool = [episode_to_msg(random_episode(spec, rng, seq=i), run=RUN, task=TASK)
                      for i in range(64)]

    def payload(self, actor_id: str, seq: int) -> bytes:
        msg = pb.Episode()
        msg.CopyFrom(self._pool[seq % len(self._pool)])
        msg.actor_id, msg.seq = actor_id, seq
        return msg.SerializeToString()


class TimedSend:
    """An inserter's `send` that keeps the latency of every request answered with an ack."""

    def __init__(self, transport: Transport, key: str, timeout_s: float) -> None:
        self.transport, self.key, self.timeout_s = transport, key, timeout_s
        self.acked: list[tuple[float, float]] = []
        """(answer time, latency s)."""

    def __call__(self, payload: bytes) -> bytes:
        start = time.monotonic()
        reply = self.transport.request(self.key, payload, timeout_s=self.timeout_s)
        end = time.monotonic()
        self.acked.append((end, end - start))  # an error reply raised above
        return reply


class Actor:
    """One actor id: `senders` inserters (1: a normal actor), each fed by its own thread,
    every `period_s` (0: as fast as it takes episodes)."""

    def __init__(self, *, name: str, senders: int, period_s: float, transport: Transport,
                 episodes: Episodes, timeout_s: float) -> None:
        self.name = name
        self.period_s = period_s
        keys = RunKeys(RUN)
        self.sends = [TimedSend(transport, keys.insert, timeout_s) for _ in range(senders)]
        self.inserters = [Inserter(send=send, actor_id=name) for send in self.sends]
        self._episodes = episodes
        self._stop = threading.Event()
        self._feeds = [threading.Thread(target=self._feed, args=(i,), daemon=True,
                                        name=f"feed-{name}-{i}") for i in range(senders)]
        for feed in self._feeds:
            feed.start()

    def _feed(self, index: int) -> None:
        stride, seq = len(self.inserters), index
        due = time.monotonic()
        while not self._stop.is_set():
            if self.period_s:
                self._stop.wait(max(0.0, due - time.monotonic()))
            if not self.inserters[index].submit(seq, self._episodes.payload(self.name, seq),
                                                stop=self._stop):
                return
            seq += stride  # each sender its own seqs: the actor's inserts are all distinct
            due = max(due + self.period_s, time.monotonic())  # no burst after a held feed

    def admitted(self) -> int:
        """Episodes stored for this actor so far (acks, less those of retries)."""
        return sum(i.counters.acked - i.counters.duplicates for i in self.inserters)

    def refused(self) -> int:
        """Attempts the inserters had to repeat (here: answered `actor_queue_full`)."""
        return sum(i.counters.retries for i in self.inserters)

    def latencies_between(self, start: float, end: float) -> list[float]:
        return [lat for send in self.sends for t, lat in send.acked if start <= t < end]

    def stop(self) -> None:
        """Stop feeding and give up what is not acked (the replay stops after this and
        answers what it still holds `unavailable`)."""
        self._stop.set()
        for inserter in self.inserters:
            inserter.close(timeout_s=0.0)

    def join(self) -> None:
        for inserter in self.inserters:
            if not inserter.join(30.0):
                say(f"an inserter of {self.name} did not stop within 30 s")


class Learner:
    """Asks for `MINIBATCHES` minibatches every `MINIBATCHES / capacity` seconds."""

    def __init__(self, transport: Transport, capacity: float) -> None:
        self.transport, self.period_s = transport, MINIBATCHES / capacity
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="learner")
        self._thread.start()

    def _run(self) -> None:
        key, due, request_id = RunKeys(RUN).sample, time.monotonic(), 0
        try:
            while not self._stop.wait(max(0.0, due - time.monotonic())):
                request_id += 1
                request = pb.SampleRequest(schema_version=SCHEMA_VERSION, run=RUN,
                                           learner_id="bench", request_id=request_id,
                                           num_minibatches=MINIBATCHES, batch_size=32)
                self.transport.request(key, request.SerializeToString(),
                                       timeout_s=SAMPLE_TIMEOUT_S)
                # a slow answer is made up for by at most one request at once
                due = max(due + self.period_s, time.monotonic() - self.period_s)
        except BaseException as exc:  # reported by `stop`
            if not self._stop.is_set():
                self.error = exc

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(SAMPLE_TIMEOUT_S + 5.0)
        if self.error is not None:
            raise RuntimeError(f"the learner's stand-in failed: {self.error!r}")


def max_min_shares(demands: dict[str, float], capacity: float) -> dict[str, float]:
    """Each actor's max-min fair share of `capacity` (water filling): those asking for less
    than an equal split get what they ask for, the rest split what is left equally."""
    shares: dict[str, float] = {}
    left, pending = capacity, dict(demands)
    while pending:
        equal = left / len(pending)
        small = {name: d for name, d in pending.items() if d <= equal}
        if not small:
            shares.update({name: equal / capacity for name in pending})
            break
        for name, demand in small.items():
            shares[name] = demand / capacity
            left -= demand
            del pending[name]
    return shares


def window(actors: list[Actor], plan: Plan, demands: dict[str, float]) -> dict[str, Any]:
    """Admitted inserts per actor over one window, against their fair shares."""
    time.sleep(plan.warmup_s)
    start, before = time.monotonic(), {a.name: a.admitted() for a in actors}
    refused0 = {a.name: a.refused() for a in actors}
    time.sleep(plan.window_s)
    end = time.monotonic()
    rates = {a.name: (a.admitted() - before[a.name]) / (end - start) for a in actors}
    total = sum(rates.values())
    fair = max_min_shares(demands, total)
    rows = {}
    for actor in actors:
        share = rates[actor.name] / total if total else 0.0
        lat_ms = [lat * 1e3 for lat in actor.latencies_between(start, end)]
        rows[actor.name] = {
            "admitted_per_s": rates[actor.name], "share": share,
            "fair_share": fair[actor.name],
            "share_over_fair": share / fair[actor.name] if fair[actor.name] else 0.0,
            "ack_latency_p50_ms": float(np.percentile(lat_ms, 50)) if lat_ms else None,
            "ack_latency_p95_ms": float(np.percentile(lat_ms, 95)) if lat_ms else None,
            "retries": actor.refused() - refused0[actor.name]}
    return {"window_s": end - start, "admitted_per_s": total, "actors": rows}


def measure_mode(name: str, per_actor: int, *, plan: Plan, endpoint: str, workdir: Path,
                 episodes: Episodes, clients: list[Transport]) -> dict[str, Any]:
    config = apply_overrides(HercsConfig(), [
        f"run.name={RUN}", f"run.run_dir={workdir / f'runs-{per_actor}'}", f"task.name={TASK}",
        "run.method=her", "training.max_policy_lag=-1", "replay.log_scene=false",
        "training.episodes_per_cycle=4", "training.minibatches_per_cycle=4",  # ρ = 1
        "replay.min_episodes_to_sample=4", "replay.rate_tolerance_updates=8",
        "replay.buffer_transitions=100000", "ddpg.batch_size=32",
        f"replay.waiting_inserts_per_actor={per_actor}",
        f"transport.connect=[{endpoint}]", f"transport.listen=[{endpoint}]"])
    path = workdir / f"config-{per_actor}.yaml"
    save_yaml(config, path)
    status = Latest()
    watch = clients[0].subscribe(RunKeys(RUN).status,
                                 lambda _, raw: status.set(pb.ReplayStatus.FromString(raw)),
                                 drop_oldest=True, capacity=4)
    replay = Child(role="replay", ident=f"replay-{per_actor}", config_path=path,
                   log_dir=workdir)
    actors: list[Actor] = []
    learner: Learner | None = None
    try:
        if status.wait_for(lambda s: True, READY_TIMEOUT_S) is None:
            replay.check_alive()
            raise RuntimeError(f"the replay sent no status within {READY_TIMEOUT_S:g} s")
        timeout_s = config.actor.insert_timeout_s
        learner = Learner(clients[1], plan.capacity)
        make = functools.partial(Actor, episodes=episodes, timeout_s=timeout_s)
        flooder = make(name="flooder", senders=FLOOD_SENDERS, period_s=0.0,
                       transport=clients[2])
        actors.append(flooder)
        say(f"{name}: the flooder alone")
        alone = window([flooder], plan, {"flooder": float("inf")})
        for i in range(NORMAL_ACTORS):
            actors.append(make(name=f"normal-{i}", senders=1, period_s=1 / plan.normal_rate,
                               transport=clients[3 + i]))
        say(f"{name}: the flooder and {NORMAL_ACTORS} normal actors")
        demands = {a.name: (float("inf") if a is flooder else plan.normal_rate)
                   for a in actors}
        shared = window(actors, plan, demands)
        replay.check_alive()
        final = status.wait_for(lambda s: True, 5.0)
        rejects = dict(final.rejects) if final is not None else {}
    finally:
        if learner is not None:
            learner.stop()
        for actor in actors:
            actor.stop()
        replay.stop()
        for actor in actors:
            actor.join()
        watch.close()
    return {"waiting_inserts_per_actor": per_actor, "alone": alone, "shared": shared,
            "replay_rejects": rejects}


def report(results: dict[str, Any], *, plan: Plan, command: str) -> str:
    lines = ["# Fair sharing of the insert capacity between actors", "",
             f"`{command}` — git {results['git']}; {results['machine']['cpu']}, shared with "
             "other work. A real replay (Zenoh on loopback, episode log fsynced); the "
             f"learner's stand-in makes room for {plan.capacity:g} inserts/s (ρ = 1, "
             f"{MINIBATCHES} minibatches per request); 1 flooding actor ({FLOOD_SENDERS} "
             f"inserters under one actor id, fed as fast as they take episodes) and "
             f"{NORMAL_ACTORS} normal actors (one inserter each, {plan.normal_rate:g} "
             f"episodes/s offered); {plan.window_s:g} s windows after {plan.warmup_s:g} s "
             "of warm-up. Fair share: the max-min share of the admitted inserts (a normal "
             "actor is owed all it offers, the flooder the rest).", "",
             "| mode | actor | admitted/s | share | fair share | share / fair | ack p50 ms "
             "| ack p95 ms | retries |", "|---|---|---|---|---|---|---|---|---|"]
    for mode, res in results["modes"].items():
        for name, row in res["shared"]["actors"].items():
            p50, p95 = row["ack_latency_p50_ms"], row["ack_latency_p95_ms"]
            lines.append(
                f"| {mode} | {name} | {row['admitted_per_s']:.1f} | {row['share']:.3f} | "
                f"{row['fair_share']:.3f} | {row['share_over_fair']:.2f} | "
                f"{'—' if p50 is None else f'{p50:.0f}'} | "
                f"{'—' if p95 is None else f'{p95:.0f}'} | {row['retries']} |")
    lines += ["", "| mode | worst normal actor's share / fair share | flooder's share / fair "
              "share | admitted/s, all | admitted/s, the flooder alone |", "|---|---|---|---|---|"]
    for mode, res in results["modes"].items():
        lines.append(f"| {mode} | {res['worst_normal_over_fair']:.2f} | "
                     f"{res['shared']['actors']['flooder']['share_over_fair']:.2f} | "
                     f"{res['shared']['admitted_per_s']:.1f} | "
                     f"{res['alone']['admitted_per_s']:.1f} |")
    lines += ["", f"The flooder alone, round-robin against arrival order: "
              f"{results['alone_ratio']:.2f} × the admitted inserts/s (1.00: unchanged)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="short windows")
    parser.add_argument("--out", default=str(REPO / "docs/results/fair_share"))
    args = parser.parse_args(argv)
    plan = QUICK if args.quick else FULL
    logging.basicConfig(level=logging.WARNING)
    logging.getLogger("hercs.actors.inserter").setLevel(logging.ERROR)  # the flooder's retries
    spec = apply_overrides(HercsConfig(), [f"task.name={TASK}"]).task.spec
    episodes = Episodes(spec)
    endpoint = free_endpoint()
    router = open_router([endpoint])
    clients: list[Transport] = []
    modes: dict[str, Any] = {}
    try:
        for _ in range(3 + NORMAL_ACTORS):  # status, learner, flooder, normal actors
            clients.append(Transport.open(mode="client", connect=[endpoint],
                                          connect_timeout_s=30.0))
        with tempfile.TemporaryDirectory(dir=REPO) as workdir:  # the repository's disk
            for mode, per_actor in MODES.items():
                modes[mode] = measure_mode(mode, per_actor, plan=plan, endpoint=endpoint,
                                           workdir=Path(workdir), episodes=episodes,
                                           clients=clients)
    finally:
        for client in clients:
            client.close()
        router.close()
    for res in modes.values():
        res["worst_normal_over_fair"] = min(
            row["share_over_fair"] for name, row in res["shared"]["actors"].items()
            if name != "flooder")
    before, after = (modes[m]["alone"]["admitted_per_s"] for m in MODES)
    command = "python -m bench.perf.fair_share" + (" --quick" if args.quick else "")
    results = {"git": git_commit(), "machine": machine_identity(), "command": command,
               "plan": dataclasses.asdict(plan), "flood_senders": FLOOD_SENDERS,
               "normal_actors": NORMAL_ACTORS, "modes": modes,
               "alone_ratio": after / before if before else 0.0}
    text = report(results, plan=plan, command=command)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(results, indent=2) + "\n")
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
