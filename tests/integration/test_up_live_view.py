"""`hercs up --rerun URL --rerun-save FILE.rrd` end to end, with the real services and a real
Rerun gRPC server standing in for the viewer: the run finishes as without a live view, the
.rrd verifies and holds what `hercs view` shows for the same run, and the viewer got the
stream too."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from hercs.apps.launch.router import free_port
from hercs.apps.views.view import read_run_log
from hercs.run.rundir import RunDir
from tests.integration.launcher_standins import Launcher, process_alive
from tests.support import free_endpoint, rerun_viewer

pytestmark = [pytest.mark.integration, pytest.mark.slow]

RERUN = Path(sys.executable).parent / "rerun"
EVERY = 10


def _entities(listing: str) -> set[str]:
    """Entity paths in `rerun rrd print` output (" - /path - " per chunk)."""
    return {"/" + line.split(" - /", 1)[1].split(" - ", 1)[0]
            for line in listing.splitlines() if " - /" in line}


def test_up_streams_the_run_live_to_a_viewer_and_an_rrd(tmp_path: Path) -> None:
    port = free_port()
    saved = tmp_path / "live.rrd"
    with rerun_viewer(port, tmp_path / "received.rrd"):  # ends its file on exit
        launcher = Launcher(
            [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--method", "her-cs",
             "--epochs", "1", "--run", "live", "--run-dir", str(tmp_path / "runs"),
             "--listen", free_endpoint(), "--rerun", str(port), "--rerun-save", str(saved),
             "--rerun-every", str(EVERY),
             "--set", "training.cycles_per_epoch=2", "--set", "training.eval_episodes=2",
             "--set", "training.episodes_per_cycle=8", "--set", "training.minibatches_per_cycle=2",
             "--set", "cluster.fgb_size=4", "--set", "cluster.k=2",
             # lockstep: the replay holds the next cycle until the model due is fitted, so the
             # run cannot end before the clusterer's first fit, however fast or loaded
             "--set", "training.schedule=lockstep"],
            cwd=tmp_path)
        try:
            assert launcher.finish(timeout_s=180) == 0, "\n".join(launcher.out + launcher.err)
            assert not [i for i, pid in launcher.child_pids.items() if process_alive(pid)]
        finally:
            launcher.kill()

    run_dir = tmp_path / "runs" / "live"
    assert list(launcher.child_pids)[:2] == ["replay-0", "live-0"]
    assert "exited unexpectedly" not in "\n".join(launcher.err)
    live_log = (RunDir(run_dir).log("live-0")).read_text()
    assert "live view done" in live_log and "Traceback" not in live_log, live_log

    verified = subprocess.run([str(RERUN), "rrd", "verify", str(saved)], capture_output=True,
                              text=True, timeout=120)
    assert verified.returncode == 0, verified.stderr
    printed = subprocess.run([str(RERUN), "rrd", "print", str(saved)], capture_output=True,
                             text=True, timeout=120, check=True).stdout
    entities = _entities(printed)
    run = read_run_log(run_dir)  # what `hercs view` reads: every acked episode and model
    # The epoch cannot end before 16 episodes are stored; an untrained FetchReach policy fails
    # nearly all of them, the first fit is due at 4 failed goals, and lockstep serves no
    # cycle past that point before the model is in.
    assert len(run.episodes) >= 16 and run.models, (len(run.episodes), len(run.models))
    expected = {"/world", "/curves/success_rate", "/curves/env_steps_per_s", "/episodes/success",
                "/episodes/final_distance", "/episodes/cluster", "/world/failed_goals",
                "/world/centroids", "/log/cluster_models", "/log/episodes"}
    drawn = [e.episode_id for e in run.episodes if e.episode_id % EVERY == 0]
    expected |= {f"/world/episodes/{i:06d}/{part}" for i in drawn for part in ("gripper",
                                                                                "goal")}
    assert expected <= entities, sorted(expected - entities)
    assert {e for e in entities if e.startswith("/world/episodes/")} == {
        f"/world/episodes/{i:06d}/{part}" for i in drawn for part in ("gripper", "goal")}
    assert "/world/episodes/000000/object" not in entities  # reach has no object

    # every stored episode got its scalars, with the success `hercs view` computes
    success = {}
    for chunk in RrdReader(saved).stream():
        if chunk.entity_path == "/episodes/success" and not chunk.is_static:
            table = chunk.to_record_batch().select(["episode", "Scalars:scalars"]).to_pylist()
            success.update({r["episode"]: r["Scalars:scalars"][0] for r in table})
    assert success == {e.episode_id: float(e.success) for e in run.episodes}

    # the viewer (a gRPC server saving what it receives) got the same stream
    received = subprocess.run([str(RERUN), "rrd", "print", str(tmp_path / "received.rrd")],
                              capture_output=True, text=True, timeout=120).stdout
    assert {"/episodes/success", "/curves/success_rate", "/world/episodes/000000/gripper"} <= (
        _entities(received))
