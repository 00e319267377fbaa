"""What `hercs view` opens on (issue 47): the 3D view looks at the table from the robot's side,
goals are small points and centroids large ones, and only the centroids carry labels."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hercs.apps.views.rerun_draw import (
    CENTROID_POINTS,
    FAILED_GOAL_POINTS,
    GOAL_POINTS,
    GRIPPER_PATH_POINTS,
    OBJECT_PATH_POINTS,
)
from hercs.apps.views.rerun_layout import (
    FETCH_EYE,
    FETCH_ROBOT_BASE_X,
    FETCH_TABLE_CENTRE,
    default_eye,
)
from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.run.runlog import TOPIC_CLUSTER_MODEL, read_messages
from hercs.wire.codec import msg_to_cluster_model
from tests.unit.apps.test_view import RERUN, _write_run

DEMO = Path(__file__).resolve().parents[3] / "docs" / "demo" / "push-her-cs"


@pytest.mark.parametrize("task", ["reach", "push", "pick", "slide", "FetchPush-v1"])
def test_a_fetch_task_opens_on_the_table_from_the_robots_side(task: str) -> None:
    eye = default_eye(task_spec(task))
    assert eye == FETCH_EYE and eye.look_target == FETCH_TABLE_CENTRE
    (x, y, z), (tx, ty, tz) = eye.position, eye.look_target
    assert FETCH_ROBOT_BASE_X < x < tx, "between the robot and the goals, on the robot's side"
    assert y == ty and eye.up == (0.0, 0.0, 1.0)
    assert 30 <= math.degrees(math.atan2(z - tz, tx - x)) <= 60, "above the table, not edge-on"


def test_other_families_keep_rerun_s_own_camera() -> None:
    assert default_eye(task_spec("HandReach-v3")) is None
    assert default_eye(None) is None


def test_the_camera_looks_at_the_committed_demo_s_clusters() -> None:
    centroids = np.concatenate([
        msg_to_cluster_model(m.decode_as(pb.ClusterModel)).centroids
        for m in read_messages(DEMO, [TOPIC_CLUSTER_MODEL])])
    assert len(centroids) == 4 * 8
    off = np.abs(centroids - np.array(FETCH_TABLE_CENTRE)).max()
    assert off < 0.2, f"a centroid {off:.2f} m from where the camera looks"


def test_goals_and_paths_are_thin_and_centroids_large() -> None:
    thin = max(FAILED_GOAL_POINTS, OBJECT_PATH_POINTS, GRIPPER_PATH_POINTS)
    assert thin < GOAL_POINTS < CENTROID_POINTS / 2


def test_only_the_centroids_are_labelled_and_the_layout_holds_the_camera(
        tmp_path: Path) -> None:
    _write_run(tmp_path)
    out = tmp_path / "out.rrd"
    subprocess.run([sys.executable, "-m", "hercs.apps.cli", "view", str(tmp_path), "--save",
                    str(out), "--episodes", "all"], capture_output=True, text=True,
                   timeout=120, check=True)
    printed = subprocess.run([str(RERUN), "rrd", "print", "-vv", str(out)],
                             capture_output=True, text=True, timeout=120, check=True).stdout
    chunks = {}
    for chunk in printed.split("Chunk(")[1:]:
        entity = re.search(r" - (/\S*) - ", chunk)
        assert entity is not None
        chunks.setdefault(entity.group(1), []).append(chunk)
    labelled = {e for e, cs in chunks.items() if any("Points3D:labels" in c for c in cs)}
    assert labelled == {"/world/centroids"}
    assert any(e.endswith("/EyeControls3D") for e in chunks), "no camera in the blueprint"
    on_epoch = {e for e, cs in chunks.items() if any("index_name: epoch" in c for c in cs)}
    assert on_epoch and all(e.startswith("/curves/") for e in on_epoch), on_epoch
