"""A chaos soak's record (`chaos.json`, one per run, bench/faults/chaos.py): the schedule and
every injection, each with the times from its end to the target's return, the next insert and
the next epoch, and bench.faults.net_measure's row of the whole run. What is reported:
docs/FAULTS.md, "The chaos soak".
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.common import git_commit, machine_identity
from bench.faults.chaos_actors import Incarnation
from bench.faults.chaos_envelope import (
    success_curve,
)
from bench.faults.chaos_state import SoakState
from bench.faults.net_measure import measure, stored_episodes
from bench.faults.service_kills import EPOCH

RECORD = "chaos.json"


def _first(times: Sequence[float], after: float) -> float | None:
    later = [t for t in times if t >= after]
    return round(min(later) - after, 2) if later else None


def annotate(state: SoakState, run_dir: Path) -> list[dict[str, Any]]:
    """The injections, each with `back_s`, `next_insert_s` and `next_epoch_s` (None: never)."""
    pairs, times = stored_episodes(run_dir)
    epochs = [t for t, line in state.progress if EPOCH.match(line)]
    actors = {a["ident"] for a in state.actors}
    annotated = []
    for record in state.injections:
        record = dict(record)
        if record["kind"] in ("kill", "cut"):
            target, start = record["target"], record["at_s"]
            end = record.get("healed_at_s", start)
            end_wall = record.get("healed_wall_s", record["wall_s"])
            if target in actors:  # its session (a new one after a kill) seen by the router
                back = re.compile(rf"^hercs up: remote actor {re.escape(target)}(@\S+)? joined")
            elif target == "launcher":
                back = re.compile(r"^hercs up: resuming run")
            else:
                back = re.compile(rf"^hercs up: started \w+ {re.escape(target)} again")
            record["back_s"] = _first([t for t, line in state.progress if back.match(line)],
                                      end)
            ours = [(actor_id, t) for (actor_id, _), t in zip(pairs, times, strict=True)
                    if target not in actors or actor_id.startswith(f"{target}@")]
            if record["kind"] == "kill" and target in actors:
                # a new incarnation's: the replay may still store what the killed one sent
                old = {actor_id for actor_id, t in ours if t < end_wall}
                ours = [(actor_id, t) for actor_id, t in ours if actor_id not in old]
            record["next_insert_s"] = _first([t for _, t in ours], end_wall)
            record["next_epoch_s"] = _first(epochs, end)
        annotated.append(record)
    return annotated


def measure_soak(state: SoakState, *, run_root: Path) -> dict[str, Any]:
    """The record of a soak whose run has ended (or, unfinished, as far as it got)."""
    run_dir = run_root / state.name
    history = [Incarnation(**a) for a in state.actors]
    kills = [r for r in state.injections if r["kind"] == "kill"]
    cuts = [r for r in state.injections if r["kind"] == "cut"]
    done = [r for r in kills if r["outcome"] == "done"]
    stops = sum(r["kind"] == "interrupted" for r in state.injections)
    injected = (f"kills: {len(done)} ({len(kills) - len(done)} skipped), cuts: {len(cuts)}"
                if state.chaos_seed is not None else "nothing")
    if stops:
        injected += f"; the bench itself stopped {stops}× and resumed"
    notes = list(state.notes)
    if not state.finished:
        notes.append("the soak has not finished (an interrupted state read back)")
    result = measure(
        setting=state.name, injected=injected, run_dir=run_dir,
        actor_logs={i.key: run_root / i.log for i in history},
        epochs_expected=int(state.shape["epochs"]),
        exit_status=state.up_exits[-1] if state.up_exits else -1,
        actor_exits=[-1 if i.exit is None else i.exit for i in history if not i.killed_by],
        progress=state.progress, healed_wall_s=None, next_epoch_after_heal_s=None,
        wall_s=state.elapsed_s, load_before=min(state.loads, default=0.0),
        load_after=max(state.loads, default=0.0), notes=notes,  # the range over its sessions
        killed=frozenset(i.key for i in history if i.killed_by))
    ok = result.ok and state.finished
    horizon = state.elapsed_s
    return {
        "name": state.name, "chaos_seed": state.chaos_seed, "quick": state.quick,
        "shape": state.shape, "plan": state.plan,
        "schedule": [e for e in state.events if e["at_s"] <= horizon],
        "schedule_drawn": len(state.events),
        "injections": annotate(state, run_dir), "actor_incarnations": state.actors,
        "up_exits": state.up_exits, "result": {**asdict(result), "stored_twice":
                                                result.stored_twice, "ok": result.ok},
        "success": success_curve(run_dir), "ok": ok, "commit": git_commit(),
        "machine": machine_identity(),
        "measured": datetime.now(UTC).isoformat(timespec="seconds")}
