"""`hercs eval RUN`: load a trained policy and evaluate, watch or record it, no service running.

`--checkpoint` is `best` (default when present), `latest` (`learner.pt`), an epoch N
(`epoch-NNNN.pt`) or a file. By default the episodes are the ones the run's evaluator used for
that epoch (its env, seeded from the run seed and advanced by the earlier epochs' episodes),
so for a run evaluated in order the first `training.eval_episodes` reproduce `metrics.csv`'s
success; `--seed S` draws other goals. Actions are μ without noise.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hercs.apps.evaluation.recorded import comparison, made_on, recorded_success
from hercs.apps.evaluation.video_frames import TITLE_S, AnnotatedEpisodes, outcome_text
from hercs.apps.evaluation.zoo import ZOO_PREFIX, zoo_folder
from hercs.apps.tracking.session import open_tracking
from hercs.config import HercsConfig
from hercs.errors import HercsError
from hercs.rl.seeding import int_seed
from hercs.rl.task_registry import TaskSpec, goal_distance
from hercs.run.policy_files import LoadedPolicy, read_policy
from hercs.run.rundir import RunDir

log = logging.getLogger(__name__)

FPS = 25
"""Video frame rate: the Fetch control period is 0.04 s, so the video plays in real time."""
FRAME_SIZE = (1280, 720)
"""Video frames, width × height: 720p, where a Fetch object is 30–55 px wide (`CAMERAS`)."""
GL_BACKENDS = ("egl", "osmesa")
_TABLE = {"distance": 1.1, "azimuth": 150.0, "elevation": -40.0, "lookat": (1.34, 0.75, 0.5)}
CAMERAS: dict[str, dict[str, Any]] = {
    "FetchReach": _TABLE, "FetchPush": _TABLE, "FetchPickAndPlace": _TABLE,
    # Slide's goals lie up to 0.6 m beyond the puck, along its longer table
    "FetchSlide": {"distance": 1.25, "azimuth": 150.0, "elevation": -50.0,
                   "lookat": (1.3, 0.75, 0.42)},
}
"""The video's camera per Fetch task on MuJoCo 3 (v4): from the front left, looking down on
the table where the object and goals are (x 1.2–1.5 m, y 0.6–0.9 m, goals up to 0.45 m above
it; Slide's x 0.9–1.7 m); the environment's own camera, from 2.5 m, shows the whole robot
with the object a few pixels wide. A v1 env (mujoco-py) and any other task keep their own."""


class EvalError(HercsError):
    """The run, checkpoint or renderer cannot be used as asked; the message says what to do."""


@dataclass
class EvalSummary:
    episodes: int
    successes: int
    mean_final_distance: float
    frames: int

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes


def choose_gl() -> str:
    """The MuJoCo offscreen backend: MUJOCO_GL if set, else the first of EGL, OSMesa that can
    make a context here (each tried in a child process: MuJoCo fixes it at import)."""
    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    probe = "import mujoco; c = mujoco.GLContext(16, 16); c.make_current(); c.free()"
    errors = []
    for backend in GL_BACKENDS:
        with tempfile.TemporaryDirectory() as scratch:  # MuJoCo logs failures to its cwd
            done = subprocess.run([sys.executable, "-c", probe], capture_output=True,
                                  text=True, cwd=scratch, timeout=120,
                                  env={**os.environ, "MUJOCO_GL": backend,
                                       "PYOPENGL_PLATFORM": backend})
        if done.returncode == 0:
            return backend
        errors.append(f"{backend}: {(done.stderr.strip().splitlines() or ['?'])[-1]}")
    raise EvalError("no offscreen OpenGL for MuJoCo here (" + "; ".join(errors) + "); install "
                    "EGL (libegl1) or OSMesa (libosmesa6), or evaluate without --video")


def video_camera(spec: TaskSpec) -> dict[str, Any] | None:
    """The camera `hercs eval --video` films `spec`'s env with (`CAMERAS`), None for its own."""
    return CAMERAS.get(spec.env_name) if spec.env_version == "v4" else None


def video_env(spec: TaskSpec) -> Any:
    """The env `hercs eval --video` films: `FRAME_SIZE` frames from `video_camera(spec)`, and
    where that is a Fetch camera, without the mocap body's guide lines (metre-long green bars,
    drawn only, that cross the table once the gripper moves)."""
    from hercs.rl.envs import make_env

    camera = video_camera(spec)
    env = make_env(spec, render_mode="rgb_array", size=FRAME_SIZE, camera=camera)
    if camera is not None:
        import mujoco  # type: ignore[import-untyped]

        model = env.unwrapped.model  # type: ignore[attr-defined]  # a MuJoCo robot env's
        mocap = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "robot0:mocap")
        model.geom_rgba[model.geom_bodyid == mocap, 3] = 0.0
    return env


def evaluate(policy: LoadedPolicy, *, episodes: int, seed: int | None = None,
             render: bool = False, on_frame: Any = None,
             on_episode_end: Callable[[int, bool, float], None] | None = None) -> EvalSummary:
    """Run `episodes` deterministic episodes; with `render`, `on_frame(episode, step, rgb)`
    gets T + 1 frames per episode (the start and after every step). `on_episode_end(episode,
    success, final distance)` follows each episode."""
    from hercs.actors.rollout import RolloutWorker
    from hercs.rl.envs import make_env

    config, spec = policy.config, policy.config.task.spec
    actor = policy.policy()
    env = video_env(spec) if render else make_env(spec)
    if seed is None:  # the evaluator's stream: its seed, past the earlier epochs' episodes
        worker = RolloutWorker(spec=spec, env=env, seed=int_seed(config.run.seed, "evaluator"))
        worker.skip((policy.epoch - 1) * config.training.eval_episodes)
    else:
        worker = RolloutWorker(spec=spec, env=env, seed=seed)
    successes, distances, frames = 0, [], 0
    try:
        for n in range(episodes):
            step = 0

            def act(o: np.ndarray, g: np.ndarray, n: int = n) -> np.ndarray:
                nonlocal step, frames
                if render:
                    on_frame(n, step, env.render())
                    frames += 1
                step += 1
                return actor.act(o, g, explore=False)

            episode = worker.run_episode(act)
            if render:
                on_frame(n, step, env.render())
                frames += 1
            successes += int(episode.success)
            distances.append(float(goal_distance(episode.final_ag, episode.desired_goal)))
            if on_episode_end is not None:
                on_episode_end(n, bool(episode.success), distances[-1])
    finally:
        worker.close()
    return EvalSummary(episodes=episodes, successes=successes,
                       mean_final_distance=float(np.mean(distances)), frames=frames)


def run_eval(run_dir: str, *, checkpoint: str | None, episodes: int, seed: int | None,
             video: str | None, rerun_save: str | None) -> int:
    """`hercs eval`: prints the summary; 0 on success, 2 for a bad run/checkpoint/renderer."""
    if episodes < 1:
        print(f"hercs eval: --episodes {episodes}: must be >= 1", file=sys.stderr)
        return 2
    closers: list[Any] = []
    try:
        render = video is not None or rerun_save is not None
        if render:
            os.environ["MUJOCO_GL"] = choose_gl()
        run_dir = str(zoo_folder(run_dir)) if run_dir.startswith(ZOO_PREFIX) else run_dir
        policy = read_policy(run_dir, checkpoint)
        sinks, closers = _sinks(video, rerun_save, episodes)
        outcomes: list[tuple[bool, float]] = []

        def episode_end(n: int, success: bool, distance: float) -> None:
            outcomes.append((success, distance))
            for sink in sinks:
                sink.episode_end(n, success, distance)

        summary = evaluate(
            policy, episodes=episodes, seed=seed, render=render,
            on_frame=lambda n, t, rgb: [sink.frame(n, t, rgb) for sink in sinks],
            on_episode_end=episode_end)
    except HercsError as exc:  # a bad run, checkpoint or renderer; a v1 run without mujoco-py
        print(f"hercs eval: {exc}", file=sys.stderr)
        return 2
    finally:
        for close in closers:
            close()
    spec = policy.config.task.spec
    print(f"hercs eval: {policy.config.run.name} ({spec.name}, {policy.config.run.method}), "
          f"policy of epoch {policy.epoch} from {policy.source.name}: success "
          f"{summary.success_rate:.2f} ({summary.successes}/{summary.episodes}), mean final "
          f"distance {summary.mean_final_distance:.3f} m")
    recorded = recorded_success(Path(run_dir), policy.epoch,
                                policy.config.training.eval_episodes)
    if recorded is not None:  # the run's own number beside this one, and if these episodes are its
        print("hercs eval: " + comparison(recorded, outcomes, seed=seed,
                                          from_best=policy.source.name == "best.pt",
                                          run_cpu=made_on(Path(run_dir))))
    if video:
        written = sinks[0].frames
        print(f"hercs eval: video {video}: {written} frames at {FPS} fps "
              f"({written / FPS:.1f} s): each episode after a {TITLE_S:g} s title, its "
              "frames marked with the step, and its outcome and final distance")
        video_to_trackers(run_dir, policy.config, Path(video))
    if rerun_save:
        print(f"hercs eval: Rerun recording {rerun_save} (camera images on the `step` timeline)")
    return 0


def video_to_trackers(run_dir: str, config: HercsConfig, video: Path) -> list[str]:
    """Add the video to the tracker runs (W&B, MLflow) of the run in `run_dir`, where it was
    tracked (its tracking.json); the trackers that hold it. No run makes a video while it
    trains, so this is where one reaches them."""
    folder = Path(run_dir)
    if not RunDir(folder).tracking.is_file():
        return []
    tracking = open_tracking(config, folder, attach=True, say=lambda line: print(
        f"hercs eval: warning: {line}", file=sys.stderr, flush=True))
    if tracking is None:
        return []
    tracking.video(video)
    holding = tracking.close(complete=True)
    if holding:
        print(f"hercs eval: video {video} added to the run's {' and '.join(holding)} "
              f"run{'s' if len(holding) > 1 else ''}")
    return holding


class _RerunSink:
    """Camera images on the `step` and `episode` timelines, and each episode's outcome."""

    def __init__(self, path: str) -> None:
        import rerun as rr

        self._rr = rr
        self.recording = rr.RecordingStream("hercs-eval")
        self.recording.save(path)
        self._step = 0

    def frame(self, n: int, t: int, rgb: np.ndarray) -> None:
        self.recording.set_time("step", sequence=self._step)
        self.recording.set_time("episode", sequence=n)
        self.recording.log("camera", self._rr.Image(rgb))
        self._step += 1

    def episode_end(self, n: int, success: bool, distance: float) -> None:
        self.recording.log("outcome", self._rr.TextLog(
            f"episode {n + 1}: {outcome_text(success, distance)}",
            level="INFO" if success else "WARN"))


def _sinks(video: str | None, rerun_save: str | None, episodes: int
           ) -> tuple[list[Any], list[Any]]:
    """(frame sinks, their close functions) for --video (first) and --rerun-save."""
    sinks: list[Any] = []
    closers: list[Any] = []
    if video:
        import imageio_ffmpeg

        writer = imageio_ffmpeg.write_frames(video, FRAME_SIZE, fps=FPS, quality=7,
                                             macro_block_size=8)
        writer.send(None)  # start the generator
        sinks.append(AnnotatedEpisodes(lambda rgb: writer.send(np.ascontiguousarray(rgb)),
                                       episodes=episodes, fps=FPS, size=FRAME_SIZE))
        closers.append(writer.close)
    if rerun_save:
        rerun = _RerunSink(rerun_save)
        sinks.append(rerun)
        closers.append(rerun.recording.flush)
    return sinks, closers
