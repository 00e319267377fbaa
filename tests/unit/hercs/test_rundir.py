"""hercs.run.rundir: checkpoint names resolve to the files `hercs eval` and `hercs.load_policy`
read (the learner writes them under the same names, which it imports from hercs.run.rundir)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hercs.run import router_record, rundir
from hercs.run.rundir import RunDir


@pytest.mark.parametrize(
    ("checkpoint", "present", "expected"),
    [(None, {"best.pt", "learner.pt"}, "checkpoints/best.pt"),
     (None, {"learner.pt"}, "checkpoints/learner.pt"),
     ("best", set(), "checkpoints/best.pt"), ("latest", set(), "checkpoints/learner.pt"),
     ("epoch-7", set(), "checkpoints/epoch-0007.pt"), ("other/file.pt", set(), "other/file.pt")],
    ids=["default-best", "default-falls-back-to-latest", "best", "latest", "epoch", "path"])
def test_checkpoint_names_resolve(tmp_path: Path, checkpoint: str | None, present: set[str],
                                  expected: str) -> None:
    RunDir(tmp_path).checkpoints.mkdir()
    for name in present:
        (RunDir(tmp_path).checkpoints / name).write_bytes(b"")
    path = rundir.checkpoint_path(tmp_path, checkpoint)
    assert path == (tmp_path / expected if expected.startswith("checkpoints") else Path(expected))


def test_kept_checkpoints_lists_best_latest_then_epochs(tmp_path: Path) -> None:
    RunDir(tmp_path).checkpoints.mkdir()
    for name in ("epoch-0020.pt", "learner.pt", "best.pt", "epoch-0010.pt", "mine.pt"):
        (RunDir(tmp_path).checkpoints / name).write_bytes(b"")
    assert rundir.kept_checkpoints(tmp_path) == {
        "best.pt": "best", "learner.pt": "latest", "epoch-0010.pt": "epoch-10",
        "epoch-0020.pt": "epoch-20", "mine.pt": ""}


# -- router.json ------------------------------------------------------------------------------

@pytest.mark.parametrize(("listen", "local", "remote"), [
    (["tcp/127.0.0.1:4100"], ["tcp/127.0.0.1:4100"], ["tcp/127.0.0.1:4100"]),
    (["tls/0.0.0.0:4101"], ["tls/127.0.0.1:4101"], ["tls/node-a:4101"]),
    (["tcp/[::]:4102", "tcp/10.0.0.5:4103"], ["tcp/[::1]:4102", "tcp/10.0.0.5:4103"],
     ["tcp/node-a:4102", "tcp/10.0.0.5:4103"]),
], ids=["loopback", "wildcard-v4", "wildcard-v6-and-address"])
def test_router_record_gives_loopback_on_its_host_and_its_name_elsewhere(
        tmp_path: Path, listen: list[str], local: list[str], remote: list[str]) -> None:
    record = router_record.RouterRecord.for_listen(listen, host="node-a", pid=42)
    router_record.write_router(tmp_path, record)
    back = router_record.read_router(tmp_path)
    assert back == record
    assert back.endpoints_for("node-a") == local
    assert back.endpoints_for("node-b") == remote
    assert [p.name for p in tmp_path.iterdir()] == [rundir.ROUTER]  # no temporary left


def test_only_the_writer_removes_the_router_record(tmp_path: Path) -> None:
    record = router_record.RouterRecord.for_listen(["tcp/127.0.0.1:1"], pid=7)
    router_record.write_router(tmp_path, record)
    router_record.remove_router(tmp_path, pid=8)  # another launcher's: kept
    assert router_record.read_router(tmp_path) is not None
    router_record.remove_router(tmp_path, pid=7)
    assert router_record.read_router(tmp_path) is None
    router_record.remove_router(tmp_path, pid=7)  # gone already: nothing to do


def test_a_broken_router_record_is_an_error_naming_the_file(tmp_path: Path) -> None:
    (tmp_path / rundir.ROUTER).write_text('{"host": "a"}')
    with pytest.raises(rundir.RunDirError, match=r"router\.json: not a router record"):
        router_record.read_router(tmp_path)


def test_wait_router_returns_the_record_once_written_or_none_after_its_timeout(
        tmp_path: Path) -> None:
    import threading

    assert router_record.wait_router(tmp_path, timeout_s=0.6) is None
    record = router_record.RouterRecord.for_listen(["tcp/127.0.0.1:2"], host="h", pid=1)
    writer = threading.Timer(0.3, router_record.write_router, args=(tmp_path, record))
    writer.start()
    try:
        assert router_record.wait_router(tmp_path, timeout_s=10) == record
    finally:
        writer.join()
    stopped = router_record.wait_router(tmp_path / "never", timeout_s=0, stop=lambda: True)
    assert stopped is None


def test_a_folder_holding_only_a_slurm_job_holds_no_run(tmp_path: Path) -> None:
    assert not rundir.holds_a_run(tmp_path / "absent")
    (tmp_path / rundir.SLURM).mkdir()
    assert not rundir.holds_a_run(tmp_path)
    RunDir(tmp_path).episode_log.write_bytes(b"")
    assert rundir.holds_a_run(tmp_path)


def test_a_run_directory_names_every_file_it_keeps(tmp_path: Path) -> None:
    """The one place a path into a run directory is made: each name as the module's table
    gives it, relative to the folder, and the folder itself through os.fspath."""
    run = RunDir(tmp_path / "push-her-cs-s1")
    names = {"config": "config.yaml", "metrics": "metrics.csv", "checkpoints": "checkpoints",
             "logs": "logs", "router_log": "logs/router.log", "tensorboard": "tensorboard",
             "tracking": "tracking.json", "router": "router.json", "lock": "owner.lock",
             "previous": "previous", "slurm": "slurm", "episode_log": "episodes.mcap"}
    assert {attr: getattr(run, attr).relative_to(run.path).as_posix() for attr in names} == names
    assert run.log("replay-0") == run.path / "logs" / "replay-0.log"
    assert run.checkpoint("best") == run.path / "checkpoints" / "best.pt"
    assert run.checkpoint("latest") == run.path / "checkpoints" / "learner.pt"
    assert run.segment(3) == run.path / "episodes.003.mcap"
    assert (run.name, Path(run), run) == ("push-her-cs-s1", run.path, RunDir(str(run.path)))


def test_log_segments_come_in_the_order_they_were_written(tmp_path: Path) -> None:
    run = RunDir(tmp_path)
    assert RunDir(tmp_path / "absent").log_segments() == []
    for name in ("episodes.mcap", "episodes.010.mcap", "episodes.002.mcap", "episodes.x.mcap",
                 "metrics.csv"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in run.log_segments()] == ["episodes.002.mcap", "episodes.010.mcap",
                                                    "episodes.mcap"]
