"""`hercs eval --video` (hercs/apps/evaluation/policy_eval.py): a 1280×720 video of a
committed run's policy, filmed by a camera that frames the table, so the object is tens of
pixels wide, not a few as from the environment's own camera. Skipped where MuJoCo has no
offscreen OpenGL."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hercs.apps.evaluation.video_frames import band_px
from tests.support import REPO

pytestmark = pytest.mark.integration

COMMITTED_RUN = REPO / "docs" / "results" / "runs" / "push-her-cs-s1"

# The object's box on the first frame, once with the video's camera and once with the env's
# own: rendered, then rendered again with the object moved under the floor; the pixels that
# changed are the object's. One env per process (a second EGL context in one process renders
# black after a state change).
OBJECT_BOX = """
import json, os, sys
os.environ["MUJOCO_GL"] = sys.argv[1]
import mujoco
import numpy as np
from hercs.apps.evaluation.policy_eval import FRAME_SIZE, video_env
from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec

spec = task_spec(sys.argv[2])
env = (video_env(spec) if sys.argv[3] == "video" else
       make_env(spec, render_mode="rgb_array", size=FRAME_SIZE))
env.reset(seed=3)
there = env.render().astype(int)
base = env.unwrapped
qpos = base._utils.get_joint_qpos(base.model, base.data, "object0:joint").copy()
qpos[2] -= 5.0
base._utils.set_joint_qpos(base.model, base.data, "object0:joint", qpos)
mujoco.mj_forward(base.model, base.data)
rows, cols = np.nonzero(np.abs(there - env.render().astype(int)).sum(axis=2) > 30)
print(json.dumps([there.shape[1], there.shape[0], int(cols.min()), int(cols.max()),
                  int(rows.min()), int(rows.max())]))
"""


@pytest.fixture(scope="module")
def gl() -> str:
    from hercs.apps.evaluation.policy_eval import EvalError, choose_gl

    try:
        return choose_gl()
    except EvalError as exc:
        pytest.skip(f"no offscreen OpenGL on this machine: {exc}")


def test_the_eval_video_is_720p(gl: str, tmp_path: Path) -> None:
    import imageio_ffmpeg

    video = tmp_path / "push.mp4"
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "eval", str(COMMITTED_RUN),
                           "--episodes", "1", "--video", str(video)], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    reader = imageio_ffmpeg.read_frames(str(video))
    meta = next(reader)
    assert meta["size"] == (1280, 720)
    frames = [np.frombuffer(f, np.uint8).reshape(720, 1280, 3) for f in reader]
    assert len(frames) == 25 + 51  # a 1 s title, then T + 1 frames
    assert "76 frames at 25 fps" in done.stdout


@pytest.mark.parametrize(("task", "wide"), [("push", 45), ("slide", 28)])
def test_the_video_camera_frames_the_object_far_larger_than_the_envs_own(
        gl: str, task: str, wide: int) -> None:
    boxes = {}
    for camera in ("video", "own"):
        done = subprocess.run([sys.executable, "-c", OBJECT_BOX, gl, task, camera], cwd=REPO,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        boxes[camera] = json.loads(done.stdout.strip().splitlines()[-1])
    width, height, left, right, top, bottom = boxes["video"]
    assert (width, height) == (1280, 720)
    assert right - left + 1 >= wide, boxes
    assert right - left >= 1.8 * (boxes["own"][3] - boxes["own"][2]), boxes
    band = band_px(height)  # inside the picture, clear of the text bands
    assert left > 0 and right < width - 1 and top > band and bottom < height - band, boxes
