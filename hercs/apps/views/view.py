"""`hercs view`: a Rerun recording of a run's episode log (docs/DESIGN.md §6).

Reads `episodes.mcap` (one segment or a run directory's) and `metrics.csv` beside it, and logs
them to a spawned viewer (default), an `.rrd` file (`--save`) or the web viewer (`--web`).
The live view draws the same entities with hercs/apps/views/rerun_draw.py; timelines, entity paths
and colours are docs/DESIGN.md §6, "The Rerun recording".
"""

from __future__ import annotations

import os
import sys
import time
import webbrowser
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hercs.apps.views.episode_selection import (
    FALLBACK_EPISODES_PER_EPOCH,
    ViewError,
    parse_selection,
    select_episodes,
)
from hercs.apps.views.rerun_draw import (
    APP_ID,
    EpisodeSummary,
    LoggedModel,
    declare_curve,
    log_centroids,
    log_episode,
    log_episode_scalars,
    log_failed_goals,
    log_world,
    rerun_executable,
    summarize_episode,
)
from hercs.apps.views.rerun_layout import blueprint
from hercs.apps.views.web_viewer import (
    DEFAULT_BIND,
    WebViewerError,
    bind_address,
    start_web_viewer,
)
from hercs.config import load_yaml
from hercs.errors import HercsError
from hercs.proto import hercs_pb2 as pb
from hercs.rl.cluster_model import assign_clusters
from hercs.rl.task_registry import task_spec
from hercs.run.metrics import read_rows
from hercs.run.rundir import RunDir
from hercs.run.runlog import (
    LIVE_NAME,
    TOPIC_CLUSTER_MODEL,
    TOPIC_EPISODES,
    TOPIC_REPLAY_STATE,
    EpisodeLogError,
    read_eval_results,
    read_messages,
    segment_paths,
)
from hercs.wire.codec import msg_to_array, msg_to_cluster_model

# --------------------------------------------------------------------------------------------
# Reading the log


@dataclass
class RunLog:
    task: str = ""
    threshold: float = 0.05
    episodes: list[EpisodeSummary] = field(default_factory=list)
    models: list[LoggedModel] = field(default_factory=list)


def resolve_log_path(path: str | os.PathLike[str]) -> Path:
    """Check that `path` is an episode log file or a run directory holding one."""
    p = Path(path)
    if not p.exists():
        raise ViewError(f"{p}: no such file or directory; give an episodes.mcap file or a run "
                        "directory (e.g. runs/<run>/)")
    if p.is_dir() and not segment_paths(p):
        files = RunDir(p)
        if files.metrics.is_file() or files.config.is_file():  # a run, its log not kept
            raise ViewError(
                f"{p} is a run folder without its episode log ({LIVE_NAME} or "
                "episodes.NNN.mcap): a committed or copied run keeps only its small files "
                f"(config, metrics{', best policy' if files.checkpoint('best').is_file() else ''}"
                f"). Plot its curve with `hercs plot {p} -o curve.png`"
                + (f", or evaluate its policy with `hercs eval {p}`"
                   if files.checkpoint("best").is_file() else "")
                + "; the episodes of a run of your own are in its runs/RUN folder")
        raise ViewError(f"{p} holds no episode log ({LIVE_NAME} or episodes.NNN.mcap); is it "
                        "a run directory?")
    return p


def read_run_log(path: Path) -> RunLog:
    """One pass over the log: per episode its positions, success and cluster (under the latest
    cluster model logged before it; in a log whose older segments were deleted, the first
    ones kept are coloured by the model their segment's replay state holds)."""
    run = RunLog()
    centroids: np.ndarray | None = None
    next_id = 0
    spec = None
    for message in read_messages(path, [TOPIC_EPISODES, TOPIC_CLUSTER_MODEL,
                                        TOPIC_REPLAY_STATE]):
        if message.topic == TOPIC_REPLAY_STATE:  # a bounded log: the model current here
            state = message.decode_as(pb.ReplayState)
            if centroids is None and state.HasField("cluster_model"):
                centroids = msg_to_cluster_model(state.cluster_model).centroids
            continue
        if message.topic == TOPIC_CLUSTER_MODEL:
            model = msg_to_cluster_model(message.decode_as(pb.ClusterModel))
            centroids = model.centroids
            run.models.append(LoggedModel(at_episode=next_id, model=model))
            continue
        msg = message.decode_as(pb.Episode)
        if spec is None:
            spec = task_spec(msg.task)
            run.task, run.threshold = spec.name, spec.distance_threshold
        cluster = -1
        if centroids is not None:
            ag_final = msg_to_array(msg.ag, where="Episode.ag")[-1:]
            cluster = int(assign_clusters(ag_final, centroids)[0])
        summary = summarize_episode(msg, episode_id=message.sequence, spec=spec,
                                    cluster=cluster)
        summary.inserted_ns = message.publish_time_ns
        run.episodes.append(summary)
        next_id = message.sequence + 1
    return run


def episodes_per_epoch(run_dir: Path) -> tuple[int, str]:
    """How many episodes one epoch of the run has (cycles × episodes per cycle in its
    config.yaml) and where that number comes from."""
    config_path = RunDir(run_dir).config
    if config_path.is_file():
        try:
            training = load_yaml(config_path).training
            return training.episodes_per_epoch, f"one epoch, {config_path.name}"
        except HercsError as exc:
            return FALLBACK_EPISODES_PER_EPOCH, f"{config_path} unreadable: {exc}"
    return FALLBACK_EPISODES_PER_EPOCH, "no config.yaml beside the log"


def metric_columns(path: Path) -> dict[str, list[str]]:
    """metrics.csv as columns of strings ({} if absent)."""
    rows = read_rows(path)
    if not rows:
        return {}
    return {key: [row.get(key) or "" for row in rows] for key in rows[0]}


# --------------------------------------------------------------------------------------------
# Logging


def cluster_times(run: RunLog, selected: Sequence[int]) -> list[int]:
    """The `episode` times at which `world/failed_goals` is logged, in order: each refit and
    each selected episode (so that scrubbing the `episode` timeline shows them grow)."""
    return sorted(set(selected) | {m.at_episode for m in run.models})


def log_clusters(rr, rec, run: RunLog, times: Sequence[int], *, centroids: bool) -> None:
    """The centroids at each refit (with `centroids`), and the accumulated failed goals at each
    of `times` coloured by the model current then."""
    failed_ids = np.array([e.episode_id for e in run.episodes if not e.success], np.int64)
    dim = len(run.episodes[0].desired_goal) if run.episodes else 3
    failed_goals = np.array([e.desired_goal for e in run.episodes if not e.success],
                            np.float32).reshape(-1, dim)
    if centroids:
        for model in run.models:
            log_centroids(rr, rec, model)
    model_starts = np.array([m.at_episode for m in run.models], np.int64)
    for t in times:
        current = np.searchsorted(model_starts, t, side="right") - 1
        log_failed_goals(rr, rec, at_episode=t, goals=failed_goals[failed_ids <= t],
                         centroids=run.models[current].model.centroids if current >= 0
                         else None)


def _floats(values: Sequence[str]) -> np.ndarray | None:
    try:
        return np.array([float(v) if v != "" else np.nan for v in values], np.float64)
    except ValueError:
        return None


def log_curves(rr, rec, metrics: dict[str, list[str]], log_path: Path) -> list[str]:
    """Learning curves on the `epoch` timeline; returns the entity paths logged."""
    logged: list[str] = []
    if metrics and "epoch" in metrics:
        epochs = _floats(metrics["epoch"])
        if epochs is None or np.isnan(epochs).any():
            return logged
        indexes = [rr.TimeColumn("epoch", sequence=epochs.astype(np.int64))]
        done = _floats(metrics.get("episodes", []))
        if done is not None and len(done) == len(epochs) and not np.isnan(done).any():
            # also on `episode`, at the last episode of each epoch: next to the trajectories
            indexes.append(rr.TimeColumn("episode", sequence=done.astype(np.int64) - 1))
        for name, values in metrics.items():
            if name == "epoch":
                continue
            numbers = _floats(values)
            if numbers is not None:
                if np.isnan(numbers).all():
                    continue
                entity = declare_curve(rr, rec, name)
                rec.send_columns(entity, indexes=indexes,
                                 columns=rr.Scalars.columns(scalars=numbers))
                logged.append(entity)
            elif any(";" in v for v in values):  # per-cluster lists, e.g. "31;23;32"
                for epoch, value in zip(epochs.astype(np.int64), values, strict=True):
                    parts = _floats(value.split(";")) if value else None
                    if parts is None:
                        continue
                    rec.set_time("epoch", sequence=int(epoch))
                    rec.log(f"curves/{name}", rr.Scalars(parts))
                # what is logged after the curves (the clusters) is not on `epoch`
                rec.disable_timeline("epoch")
                logged.append(f"curves/{name}")
        return logged
    results = list(read_eval_results(log_path))  # no metrics.csv: the evaluator's results
    if results:
        index = rr.TimeColumn("epoch", sequence=[int(r.epoch) for r in results])
        for name in ("success_rate", "mean_final_distance"):
            entity = declare_curve(rr, rec, name)
            rec.send_columns(entity, indexes=[index], columns=rr.Scalars.columns(
                scalars=[float(getattr(r, name)) for r in results]))
            logged.append(entity)
    return logged


def build_recording(rr, rec, run: RunLog, selected: Sequence[int],
                    metrics: dict[str, list[str]], log_path: Path) -> None:
    """Log the run, what the view opens on first: the web viewer ingests and paints the
    stream in the order it is sent, and on a slow machine a few hundred chunks take it a
    minute. So the curves, the cluster models and the failed goals at the last selected
    episode come first (a few dozen chunks), then the episodes newest first, then the failed
    goals' history for scrubbing; the picture drawn once all arrived is the same."""
    log_world(rr, rec)
    log_curves(rr, rec, metrics, log_path)
    log_episode_scalars(rr, rec, run.episodes)
    times = cluster_times(run, selected)
    log_clusters(rr, rec, run, times[-1:], centroids=True)
    by_id = {e.episode_id: e for e in run.episodes}
    for episode_id in reversed(selected):
        log_episode(rr, rec, by_id[episode_id])
    log_clusters(rr, rec, run, times[:-1], centroids=False)


# --------------------------------------------------------------------------------------------
# Entry point


def headless_problem(env: Mapping[str, str]) -> str | None:
    """Why a native viewer window cannot open here (no display), or None."""
    if sys.platform.startswith("linux") and not (env.get("DISPLAY") or
                                                 env.get("WAYLAND_DISPLAY")):
        return ("no display here (neither DISPLAY nor WAYLAND_DISPLAY is set), so no viewer "
                "window can open: write a recording with --save RUN.rrd (open it elsewhere "
                "with `rerun RUN.rrd`), or serve the web viewer with --web and open its URL")
    return None


def run_view(path: str, *, save: str | None = None, episodes: str | None = None,
             web: bool = False, web_port: int | None = None, grpc_port: int | None = None,
             web_bind: str | None = None, open_browser: bool = True) -> int:
    """`hercs view`: 0 on success, 2 on a bad path or selection, or a viewer that cannot
    open (message on stderr). With `web`, the web viewer listens on `web_bind` (default:
    loopback only, `hercs.apps.views.web_viewer`)."""
    try:
        if web_bind is not None:
            if not web:
                raise ViewError(f"--web-bind {web_bind}: goes with --web (it is the address "
                                "the web viewer listens on)")
            bind_address(web_bind)  # before reading the log
        if not (save or web):
            problem = headless_problem(os.environ)
            if problem is not None:
                raise ViewError(problem)
        log_path = resolve_log_path(path)
        if episodes is not None:
            parse_selection(episodes)  # fail before reading the log
        t0 = time.perf_counter()
        run = read_run_log(log_path)
        if not run.episodes:
            raise ViewError(f"{log_path}: the log holds no episode")
        ids = [e.episode_id for e in run.episodes]
        run_dir = log_path if log_path.is_dir() else log_path.parent
        per_epoch, per_epoch_source = episodes_per_epoch(run_dir)
        selected = select_episodes(episodes, ids, last_epoch=per_epoch)
        if not selected:
            raise ViewError(f"--episodes {episodes!r} selects none of the {len(ids)} episodes "
                            f"(ids {ids[0]}..{ids[-1]})")
    except (ViewError, WebViewerError, ValueError, EpisodeLogError) as exc:
        print(f"hercs view: {exc}", file=sys.stderr)
        return 2
    metrics = metric_columns(RunDir(run_dir).metrics)

    import rerun as rr  # imported here: `hercs --help` stays fast

    rec = rr.RecordingStream(APP_ID)
    rec.send_recording_name(f"{run_dir.name} ({run.task})")
    layout = blueprint(selected, task=task_spec(run.task))
    if save:
        rec.save(save, default_blueprint=layout)
    elif web:
        try:
            viewer = start_web_viewer(bind=web_bind or DEFAULT_BIND, web_port=web_port,
                                      grpc_port=grpc_port)
        except (WebViewerError, OSError) as exc:  # OSError: no `rerun` executable to start
            print(f"hercs view: {exc}", file=sys.stderr)
            return 2
        rec.connect_grpc(viewer.stream_url, default_blueprint=layout)
    else:
        rr.spawn(recording=rec, default_blueprint=layout, executable_path=rerun_executable())
    build_recording(rr, rec, run, selected, metrics, log_path)
    rec.flush()
    if episodes is None:
        print(f"hercs view: drawing the last {len(selected)} episodes ({per_epoch_source}); "
              "--episodes all draws the whole log, --episodes spread:200 a sample of it",
              file=sys.stderr)
    print(f"hercs view: {len(selected)} of {len(ids)} episodes, {len(run.models)} cluster "
          f"models, {len(next(iter(metrics.values()), []))} epochs of metrics "
          f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    if save:
        rec.disconnect()
        print(f"wrote {save}")
    elif web:
        print(f"serving the web viewer at {viewer.page_url} (Ctrl-C stops)", flush=True)
        if open_browser:
            webbrowser.open(viewer.page_url)
        try:
            viewer.proc.wait()  # serving until Ctrl-C, or until rerun itself ends
        except KeyboardInterrupt:
            pass
        finally:
            # the stream closed before its server goes: else the SDK logs the severed
            # connection as two ERROR lines on the way out
            rec.disconnect()
            viewer.stop()
    return 0
