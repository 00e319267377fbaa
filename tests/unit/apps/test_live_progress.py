"""`hercs up`'s progress within an epoch: the learner's cycle counts (RunProgress), the time
left, the live line a terminal gets (on a real pty) and what a run of remote actors only says,
and the running epoch of a resumed run."""

from __future__ import annotations

import io
import os
import pty
import re

import pytest

from hercs.apps.launch.epoch_progress import CycleCounter
from hercs.apps.launch.live_line import LiveLine, is_terminal
from hercs.apps.launch.progress import Progress
from hercs.apps.launch.run_plan import resolve_run
from hercs.apps.launch.supervisor import waiting_for_actors_line
from hercs.config import HercsConfig, apply_overrides
from hercs.proto import hercs_pb2 as pb
from tests.support import Clock


def cycles(cycle: int, *, per_epoch: int = 50, updates: int | None = None) -> pb.RunProgress:
    return pb.RunProgress(schema_version=1, epoch=cycle // per_epoch, epochs=3, cycle=cycle,
                          cycles_per_epoch=per_epoch,
                          updates=cycle * 40 if updates is None else updates)


def test_a_resumed_runs_first_status_line_names_the_epoch_it_trains() -> None:
    """Resumed after epoch 1 of 3: the status line before any epoch ends says epoch 2 (it
    said `epoch 1/3 running` while epoch 2 ran), from the resume's checkpoint before the
    learner speaks and from the learner's cycle count once it does."""
    clock = Clock(1000.0)
    progress = Progress(total_epochs=3, first_epoch=2, clock=clock)
    clock.now += 5  # FIRST_LINE_S
    line = progress.interim()
    assert line is not None and line.startswith("epoch 2/3 running"), line

    told = Progress(total_epochs=3, clock=clock)  # no checkpoint known: the learner says it
    told.on_run_progress(cycles(50))  # its checkpoint: the end of epoch 1
    clock.now += 5
    line = told.interim()
    assert line is not None and line.startswith("epoch 2/3 running"), line
    assert told.live_status().text().startswith("epoch 2/3  cycle 0/50  updates 2000")


def test_the_cycle_counts_give_the_epochs_cycles_and_the_time_left() -> None:
    clock = Clock(0.0)
    counter = CycleCounter(clock=clock)
    assert counter.eta_s(100) is None and counter.running_epoch is None
    counter.on_run_progress(cycles(60))
    assert counter.eta_s(100) is None, "one count gives no rate"
    clock.now = 10.0
    counter.on_run_progress(cycles(70))  # 1 cycle/s
    assert (counter.running_epoch, counter.cycle_in_epoch(2)) == (2, 20)
    assert counter.eta_s(100) == pytest.approx(30.0)
    clock.now = 15.0  # no count since: 5 s of the 30 have passed
    assert counter.eta_s(100) == pytest.approx(25.0)
    assert counter.eta_s(150) == pytest.approx(75.0)
    assert counter.eta_s(70) == 0.0
    clock.now = 20.0
    counter.on_run_progress(cycles(50))  # a restarted learner, back at its checkpoint
    assert counter.cycle_in_epoch(2) == 0 and counter.eta_s(100) is None, "a new window"
    counter.on_run_progress(pb.RunProgress(schema_version=1, epoch=1, epochs=3))
    assert counter.cycle == 50, "a RunProgress without cycle counts changes nothing"


def test_the_live_status_says_cycles_steps_updates_actors_and_eta() -> None:
    clock = Clock(0.0)
    progress = Progress(total_epochs=3, clock=clock)
    progress.actors = 2
    progress.on_replay_status(pb.ReplayStatus(env_steps=15500, size_episodes=310))
    progress.on_run_progress(cycles(60))
    clock.now = 10.0
    progress.on_run_progress(cycles(81, updates=3240))
    status = progress.live_status()
    assert status.fraction == pytest.approx(31 / 50)
    assert status.text() == ("epoch 2/3  cycle 31/50  env 15500 steps  updates 3240  actors 2  "
                             "eta 9s epoch, 33s run")  # 2.1 cycles/s: 19 and 69 left


def test_a_run_of_remote_actors_only_says_it_waits_while_none_is_there() -> None:
    clock = Clock(0.0)
    progress = Progress(total_epochs=3, remote_actors_only=True, clock=clock)
    progress.actors = 0
    clock.now = 5.0
    assert "waiting for remote actors" in progress.live_status().text()
    assert (progress.interim() or "").endswith("actors 0  waiting for remote actors")
    progress.actors = 1
    assert "waiting" not in progress.live_status().text()
    assert "waiting" not in (Progress(total_epochs=3, clock=clock).live_status().text())


@pytest.mark.parametrize(
    ("overrides", "command", "where"),
    [(["transport.listen=[tcp/127.0.0.1:7447]"],
      "hercs actor --connect tcp/127.0.0.1:7447 --run R", "on this host (the router listens "
      "on loopback only; for other hosts start the run with --listen tls/0.0.0.0:7447"),
     (["transport.listen=[tcp/0.0.0.0:9000]", "security.allow_insecure=true"],
      "hercs actor --connect tcp/HOST:9000 --run R", "on any host that reaches this one"),
     (["transport.listen=[tls/0.0.0.0:7447]", "security.tls_ca=/c/ca.pem",
       "security.tls_cert=/c/{role}.pem", "security.tls_key=/c/{role}.key"],
      "hercs actor --connect tls/HOST:7447 --run R --tls-ca ca.pem --tls-cert actor.pem "
      "--tls-key actor.key", "on any host that reaches this one")],
    ids=["loopback", "any-address", "tls"])
def test_actors_0_names_the_command_that_starts_a_remote_actor(
        overrides: list[str], command: str, where: str) -> None:
    config = resolve_run(apply_overrides(HercsConfig(), [
        "run.name=R", "actor.num_actors=0", *overrides]))
    line = waiting_for_actors_line(config)
    assert line.startswith("hercs up: waiting for remote actors (--actors 0 starts none here)")
    assert line.endswith(": " + command), line
    assert where in line, line


def _read_all(fd: int) -> str:
    chunks = []
    while True:
        try:
            chunk = os.read(fd, 65536)
        except OSError:  # the other end closed (EIO on Linux)
            break
        if not chunk:
            break
        chunks.append(chunk)
    return b"".join(chunks).decode()


def test_on_a_terminal_the_live_line_is_drawn_and_lines_print_above_it() -> None:
    master, slave = pty.openpty()
    with open(slave, "w", buffering=1, closefd=True) as out:
        assert is_terminal(out) and not is_terminal(io.StringIO())
        err = io.StringIO()
        clock = Clock(0.0)
        progress = Progress(total_epochs=3, clock=clock)
        progress.on_run_progress(cycles(60))
        live = LiveLine(out, err)
        live.show(progress.live_status())
        live.say("epoch 1/3  success 0.10")
        live.say("hercs up: a child exited", error=True)
        progress.on_run_progress(cycles(75))
        live.show(progress.live_status())
        live.close()
    screen = _read_all(master)
    os.close(master)
    assert "epoch 2/3  cycle 10/50  updates 2400" in screen
    assert "epoch 2/3  cycle 25/50  updates 3000" in screen
    assert re.search(r"epoch 1/3  success 0\.10\r?\n", screen), screen
    assert err.getvalue() == "hercs up: a child exited\n"
    assert "━" in screen, "the bar of the epoch's cycles"
