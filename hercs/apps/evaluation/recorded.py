"""What a run recorded of a policy's success, and what `hercs eval`'s new estimate is to it:
metrics.csv's row at the policy's epoch (its evaluator's `training.eval_episodes` episodes), a
binomial interval beside each number, and whether the episodes were the same."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from hercs.apps.provenance import machine_identity
from hercs.run.metrics import read_rows
from hercs.run.rundir import DONE_RECORD, RunDir

SAME_DISTANCE_M = 1e-9
"""Mean final distances this close are one set of episodes computed again alike."""
CLOSE_DISTANCE_M = 1e-3
"""Mean final distances this close, with the same successes, are the same episodes whose
trajectories part in their last digits (pick-her-cs-s1, made on an Intel Xeon and evaluated on
an AMD EPYC: 3.4e-5 m apart)."""


def wilson_interval(successes: int, episodes: int, z: float = 1.96) -> tuple[float, float]:
    """The 95 % Wilson score interval of a success rate of `successes` in `episodes`."""
    if episodes <= 0:
        return 0.0, 1.0
    p = successes / episodes
    centre = p + z * z / (2 * episodes)
    spread = z * math.sqrt(p * (1 - p) / episodes + z * z / (4 * episodes * episodes))
    scale = 1 + z * z / episodes
    return max((centre - spread) / scale, 0.0), min((centre + spread) / scale, 1.0)


def rate_text(successes: int, episodes: int) -> str:
    """`0.80 (16/20, 95 % interval 0.58-0.92)`."""
    low, high = wilson_interval(successes, episodes)
    return (f"{successes / episodes:.2f} ({successes}/{episodes}, 95 % interval "
            f"{low:.2f}-{high:.2f})")


@dataclass(frozen=True)
class RecordedSuccess:
    """metrics.csv's evaluation of one epoch's policy."""

    epoch: int
    successes: int
    episodes: int
    mean_final_distance: float | None
    evaluated_epochs: int
    """Epochs metrics.csv holds: best.pt is the best of that many estimates."""

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes


def recorded_success(run_dir: Path, epoch: int, eval_episodes: int) -> RecordedSuccess | None:
    """The row of `epoch` in `run_dir`'s metrics.csv, as successes of `eval_episodes` (the
    run's `training.eval_episodes`); None where there is no such row."""
    rows = [r for r in read_rows(RunDir(run_dir).metrics) if r.get("success_rate")]
    row = next((r for r in rows if r.get("epoch") == str(epoch)), None)
    if row is None:
        return None
    distance = row.get("mean_final_distance")
    return RecordedSuccess(epoch=epoch,
                           successes=round(float(row["success_rate"]) * eval_episodes),
                           episodes=eval_episodes,
                           mean_final_distance=float(distance) if distance else None,
                           evaluated_epochs=len(rows))


def made_on(run_dir: Path) -> str | None:
    """The CPU the run finished on, as its bench_done.json records it (None: not recorded)."""
    path = run_dir / DONE_RECORD
    try:
        machine = json.loads(path.read_text()).get("machine") or {}
    except (OSError, ValueError, AttributeError):
        return None
    cpu = machine.get("cpu") if isinstance(machine, dict) else None
    return str(cpu) if cpu else None


def comparison(recorded: RecordedSuccess, outcomes: Sequence[tuple[bool, float]], *,
               seed: int | None, from_best: bool, run_cpu: str | None = None) -> str:
    """What this evaluation's episodes (`outcomes`: success and final distance, in order) are
    to the recorded ones. Without `seed` its first `recorded.episodes` are on the goals the
    evaluator drew for that epoch: the same numbers, numbers that part in their last digits,
    or another outcome, and why; with a seed, another estimate. `from_best`: the policy is
    best.pt, the best of the recorded epochs. `run_cpu`: the CPU the run finished on."""
    said = (f"metrics.csv recorded {rate_text(recorded.successes, recorded.episodes)} at epoch "
            f"{recorded.epoch}")
    if from_best and recorded.evaluated_epochs > 1:
        said += (f", the best of its {recorded.evaluated_epochs} evaluated epochs (best.pt "
                 "keeps that one, so the number is the luckiest of those estimates)")
    if seed is not None:
        return (f"{said}; these are other goals (--seed {seed}): an estimate of their own, "
                "on as many episodes as you ask for")
    first = outcomes[:recorded.episodes]
    if len(first) < recorded.episodes:
        return (f"{said}; these {len(first)} episodes are the first of its "
                f"{recorded.episodes} (--episodes {recorded.episodes} evaluates them all)")
    successes = sum(ok for ok, _ in first)
    distance = sum(d for _, d in first) / len(first)
    here = machine_identity()["cpu"]
    machine = ("" if run_cpu is None or run_cpu == here else
               f" (the run finished on {run_cpu}; this machine is {here}: one seed's numbers "
               "differ across CPUs, docs/DESIGN.md §10)")
    gap = (None if recorded.mean_final_distance is None
           else abs(distance - recorded.mean_final_distance))
    after = (f"; the {len(outcomes) - len(first)} after them are the next epoch's goals"
             if len(outcomes) > len(first) else "")
    if successes == recorded.successes and gap is not None and gap < SAME_DISTANCE_M:
        return (f"{said}; the first {len(first)} episodes here are the evaluator's of that "
                f"epoch and give the same success and final distance{after}")
    if successes == recorded.successes and gap is not None and gap < CLOSE_DISTANCE_M:
        return (f"{said}; the first {len(first)} episodes here are on the goals its evaluator "
                f"drew for that epoch and give the same success, the mean final distance "
                f"{gap:.1e} m from the recorded: the same episodes up to their last digits"
                f"{machine}{after}")
    recorded_distance = ("-" if recorded.mean_final_distance is None
                         else f"{recorded.mean_final_distance:.4f}")
    return (f"{said}; the first {len(first)} episodes here, on the goals its evaluator drew "
            f"for that epoch, give {successes / len(first):.2f} and final distance "
            f"{distance:.4f} m against {recorded.success_rate:.2f} and {recorded_distance} m: "
            "not the recorded outcome. Either its evaluator drew other goals (in a run resumed, "
            "or whose evaluator restarted, the evaluator goes on along its stream of goals, "
            "where hercs eval skips to an unbroken run's) or this machine computes the "
            "episodes otherwise, which in a contact "
            "task can turn an episode's outcome" + (machine or " (another CPU, MuJoCo or "
                                                    "mujoco-py build: docs/DESIGN.md §10)"))
