"""The default Rerun layout of `hercs view` and the live view: which views, where, and from
where the 3D view looks, so that a recording reads at a glance when it opens.

The camera is the Fetch tasks' (the only family whose scene the 3D view draws in the MuJoCo
world frame, docs/DESIGN.md §6): from behind the robot, over its shoulder, down onto the
table where the goals and the object lie. Other tasks keep Rerun's own fit to the scene.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from hercs.rl.task_registry import TaskSpec


@dataclass(frozen=True)
class Eye:
    """An orbital camera: where it sits and the point it looks at (world frame, metres)."""

    position: tuple[float, float, float]
    look_target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)


FETCH_TABLE_CENTRE = (1.35, 0.75, 0.42)
"""Where the Fetch goals lie: the committed push log's 808 desired goals span x 1.21-1.51,
y 0.60-0.90 at z 0.425 (mean 1.36, 0.74); reach goals sit above the same spot."""
FETCH_ROBOT_BASE_X = 0.40
"""The Fetch robot's base along x (gymnasium-robotics' `robot0:base_link`): the table is in
front of it along +x, so the robot's side of the table is the low-x side."""
FETCH_EYE = Eye(position=(FETCH_TABLE_CENTRE[0] - 0.36, FETCH_TABLE_CENTRE[1],
                          FETCH_TABLE_CENTRE[2] + 0.36),
                look_target=FETCH_TABLE_CENTRE)
"""Over the robot's shoulder: on its side of the table, 0.36 m short of the goals and 0.36 m
above them, so the table is seen at 45° (edge-on, the clusters hid one another) and the
goals' 0.3 m square spans over half the view's width, the objects' paths around it."""


def default_eye(task: TaskSpec | None) -> Eye | None:
    """The 3D view's opening camera for `task`, or None for Rerun's fit to the scene."""
    return FETCH_EYE if task is not None and task.family == "fetch" else None


def blueprint(selected: Sequence[int] = (), *, task: TaskSpec | None = None):
    """The default layout: the 3D scene large, the curves, per-episode scalars and the text
    logs beside it, the `episode` timeline active with the drawn episodes' span selected.
    The side panels start collapsed (the views get the whole window, the time panel keeps its
    play bar); a click opens them. With an object (push, pick, slide) the 3D view shows the
    object paths and leaves the gripper paths out (one click in the blueprint panel brings
    them back): two hundred of each hide the clusters' shapes."""
    import rerun.blueprint as rrb
    from rerun.blueprint.components import AbsoluteTimeRange

    eye = default_eye(task)
    has_object = task is not None and task.has_object
    return rrb.Blueprint(
        rrb.Horizontal(
            # one rule per path: Rerun's filters take `**` only at the end of a path
            rrb.Spatial3DView(
                origin="world", name="episodes (3D)",
                contents=(["+ world/**", *(f"- world/episodes/{i:06d}/gripper"
                                           for i in selected)]
                          if has_object else "world/**"),
                eye_controls=None if eye is None else rrb.EyeControls3D(
                    kind=rrb.Eye3DKind.Orbital, position=eye.position,
                    look_target=eye.look_target, eye_up=eye.up)),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="curves", name="success rate",
                                   contents=["curves/success_rate"]),
                rrb.TimeSeriesView(origin="curves", name="throughput",
                                   contents=["curves/env_steps_per_s", "curves/updates_per_s"]),
                rrb.TimeSeriesView(origin="episodes", name="episodes",
                                   contents=["episodes/final_distance"]),
                # one unit per panel: a panel of every curve mixed 0..1 with 0..30,000
                rrb.Tabs(
                    rrb.TimeSeriesView(origin="curves", name="losses",
                                       contents=["curves/critic_loss", "curves/actor_loss",
                                                 "curves/q_mean"]),
                    rrb.TimeSeriesView(origin="curves", name="replay size",
                                       contents=["curves/replay_size"]),
                    rrb.TimeSeriesView(origin="curves", name="policy lag",
                                       contents=["curves/policy_lag"]),
                    rrb.TimeSeriesView(origin="curves", name="clusters",
                                       contents=["curves/cluster_sizes"]),
                    rrb.TimeSeriesView(origin="curves", name="cluster share",
                                       contents=["curves/cluster_share"]),
                    rrb.TimeSeriesView(origin="episodes", name="success, cluster",
                                       contents=["episodes/success", "episodes/cluster"])),
                rrb.TextLogView(origin="log", name="log"),
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="episode", state="collapsed", time_selection=AbsoluteTimeRange(
            min=min(selected), max=max(selected)) if selected else None),
        collapse_panels=False,
    )
