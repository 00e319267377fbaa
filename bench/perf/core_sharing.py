"""What a core does while the other works: the run's two loads alone and side by side.

    python -m bench.perf.core_sharing            # 4 rounds of 5 s slices (~2 min)

The learner's update and raw env steps, each pinned to one CPU, alone, beside the other and
beside a copy of itself. Writes docs/results/core_sharing.{json,md}; docs/PERFORMANCE.md §3."""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
import traceback
from datetime import UTC, datetime
from statistics import median
from typing import Any

from bench import common

PHASES: tuple[tuple[str, ...], ...] = (("update",), ("env",), ("update", "env"),
                                       ("update", "update"), ("env", "env"))
"""The loads run at once in each phase, one process per load on its own CPU."""


def _load(kind: str):  # type: ignore[no-untyped-def]
    """A callable doing one unit of `kind` (one update, or one env step)."""
    import numpy as np

    from hercs.net.threads import single_threaded_numerics
    from hercs.rl.task_registry import task_spec

    spec = task_spec("push")
    rng = np.random.default_rng(0)
    if kind == "update":
        import torch

        from bench.perf.learner import make_batch
        from hercs.config import DDPGConfig
        from hercs.learner.ddpg import DDPGLearner

        torch.set_num_threads(1)
        single_threaded_numerics()
        learner = DDPGLearner(spec=spec, config=DDPGConfig(), seed=0)
        batches = [make_batch(spec, 256, rng) for _ in range(4)]
        count = iter(range(10**12))
        return lambda: learner.train(batches[next(count) % 4])
    from hercs.rl.envs import make_env

    single_threaded_numerics()
    env = make_env(spec)
    env.reset(seed=0)
    steps = iter(range(10**12))

    def step() -> None:
        env.step(rng.uniform(-1.0, 1.0, spec.action_dim).astype(np.float32))
        if next(steps) % spec.episode_steps == spec.episode_steps - 1:
            env.reset()
    return step


def _worker(kind: str, cpu: int, orders: Any, out: Any) -> None:
    """Build the load once, then for each order (start time, seconds) run it in that window;
    an error goes back to the parent as a message, and a worker whose parent is gone exits."""
    parent = os.getppid()
    try:
        os.sched_setaffinity(0, {cpu})
        work = _load(kind)
        for _ in range(3):
            work()
        out.put(("ready", kind, cpu, 0.0))
        while os.getppid() == parent:
            try:
                order = orders.get(timeout=5)
            except queue.Empty:
                continue
            if order is None:
                return
            start_at, slice_s = order
            time.sleep(max(0.0, start_at - time.monotonic()))  # CLOCK_MONOTONIC: one clock
            done, cpu_started = 0, time.process_time()
            while True:  # at least one unit, however late the order came
                work()
                done += 1
                if time.monotonic() - start_at >= slice_s:
                    break
            out.put(("rate", kind, cpu, done / (time.process_time() - cpu_started)))
    except BaseException:
        out.put(("error", kind, cpu, traceback.format_exc()))


START_LEAD_S = 0.5
"""How far ahead a phase's common start time is set, so that every worker has its order."""


class Workers:
    """One process per (load, CPU), built once and reused by every phase."""

    def __init__(self, cpus: list[int]) -> None:
        ctx = mp.get_context("spawn")
        self.cpus = cpus
        self.out = ctx.Queue()
        self.orders = {(kind, cpu): ctx.Queue() for kind in ("update", "env") for cpu in cpus}
        self.procs = [ctx.Process(target=_worker, args=(kind, cpu, q, self.out), daemon=True)
                      for (kind, cpu), q in self.orders.items()]
        try:
            for proc in self.procs:
                proc.start()
            for _ in self.procs:
                self._next(timeout_s=300)  # every load built and warmed
        except BaseException:
            self.close()
            raise

    def _next(self, timeout_s: float) -> tuple[str, str, int, Any]:
        """The next message from a worker; a worker's error, death or silence raises."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                message = self.out.get(timeout=1)
            except queue.Empty:
                dead = [p.name for p in self.procs if p.exitcode is not None]
                if dead:
                    raise RuntimeError(f"core_sharing: worker(s) {dead} exited") from None
                continue
            if message[0] == "error":
                raise RuntimeError(f"core_sharing: the {message[1]} load on CPU {message[2]} "
                                   f"failed:\n{message[3]}")
            return message
        raise RuntimeError(f"core_sharing: no worker answered in {timeout_s:.0f} s")

    def phase(self, loads: tuple[str, ...], slice_s: float) -> list[tuple[str, float]]:
        """The loads started together, the i-th on the i-th CPU; their rates per CPU-second."""
        start_at = time.monotonic() + START_LEAD_S
        for kind, cpu in zip(loads, self.cpus, strict=False):
            self.orders[(kind, cpu)].put((start_at, slice_s))
        results = [self._next(timeout_s=START_LEAD_S + slice_s + 60) for _ in loads]
        return [(kind, rate) for _, kind, _, rate in results]

    def close(self) -> None:
        for q in self.orders.values():
            q.put(None)
        for proc in (p for p in self.procs if p.pid is not None):  # the started ones
            proc.join(timeout=30)
            if proc.is_alive():
                proc.kill()


def measure(rounds: int, slice_s: float, cpus: list[int]) -> dict[str, list[float]]:
    """Rates per phase and load (`update alone`, `update beside env`, …), over the rounds; the
    phases' order reversed every other round."""
    found: dict[str, list[float]] = {}
    workers = Workers(cpus)
    try:
        for r in range(rounds):
            for loads in (PHASES if r % 2 == 0 else PHASES[::-1]):
                rates = workers.phase(loads, slice_s)
                for i, (kind, rate) in enumerate(rates):
                    others = [k for j, (k, _) in enumerate(rates) if j != i]
                    label = f"{kind} beside {others[0]}" if others else f"{kind} alone"
                    found.setdefault(label, []).append(rate)
    finally:
        workers.close()
    return found


def summarise(found: dict[str, list[float]]) -> dict[str, Any]:
    rates = {label: median(values) for label, values in found.items()}
    share = {label: rates[label] / rates[f"{label.split()[0]} alone"] for label in rates}
    return {"rates_per_cpu_s": rates, "share_of_alone": share, "samples": found}


def render(summary: dict[str, Any]) -> str:
    rates, share = summary["rates_per_cpu_s"], summary["share_of_alone"]
    lines = [*common.report_head(
        "bench.perf.core_sharing", "What a core does while the others work", summary,
        f"CPUs {summary['cpus']}, {summary['rounds']} rounds of {summary['slice_s']} s slices; "
        "work per CPU-second of a process pinned to one CPU (median over rounds)"),
        "| load | beside | per CPU-second | share of alone |", "|---|---|---:|---:|"]
    for label in sorted(rates):
        kind, _, other = label.partition(" beside ")
        unit = "updates" if kind.startswith("update") else "env steps"
        lines.append(f"| {kind.split()[0]} | {other or '–'} | {rates[label]:.1f} {unit} | "
                     f"{share[label]:.2f} |")
    both = (share.get("update beside env", 1.0), share.get("env beside update", 1.0))
    lines += ["", f"With the other CPU busy, the learner's update makes {both[0]:.0%} of its "
              f"rate alone and the env steps {both[1]:.0%}; the limit of docs/PERFORMANCE.md §3 "
              "counts both at 100 %."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = common.script_parser("bench.perf.core_sharing", __doc__)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--slice-s", type=float, default=5.0)
    parser.add_argument("--quick", action="store_true", help="CI: one round of 0.5 s slices")
    common.add_out_option(parser, "core_sharing")
    args = parser.parse_args(argv)
    if args.quick:
        args.rounds, args.slice_s = 1, 0.5
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        parser.error("needs at least two CPUs (sched_getaffinity names one)")
    found = measure(args.rounds, args.slice_s, cpus[:2])
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": common.git_commit(),
               "machine": common.machine_identity(), "cores": os.cpu_count(), "cpus": cpus[:2],
               "rounds": args.rounds, "slice_s": args.slice_s, "quick": args.quick,
               **summarise(found)}
    common.show_report(args, "core_sharing", summary, render(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
