"""bench/faults/net_faults.py and bench/faults/net_measure.py without a network: the acks an actor's
inserter really logs are read back, and a row that lost an acked episode or stored one twice
is not ok. The run itself is
tests/fault/test_network_faults.py."""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import pytest

from bench.faults import net_faults, net_measure
from hercs.actors.inserter import Inserter
from hercs.net.transport import TransportTimeout
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb


def test_the_acks_an_inserter_logs_are_read_back(caplog: pytest.LogCaptureFixture,
                                                 tmp_path: Path) -> None:
    """Seq 0 acked at once; seq 1's first reply lost (a timeout), its retry acked as a
    duplicate: the actor log says both were acked, one of them as a duplicate."""
    attempts: dict[int, int] = {}

    def send(payload: bytes) -> bytes:
        seq = int(payload.decode())
        attempts[seq] = attempts.get(seq, 0) + 1
        if seq == 1 and attempts[seq] == 1:
            raise TransportTimeout("hercs/r/replay/insert", 10.0, "no reply")  # reply lost
        return pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id="far@1", seq=seq,
                            duplicate=attempts[seq] > 1).SerializeToString()

    caplog.set_level(logging.DEBUG, logger="hercs.actors.inserter")
    inserter = Inserter(send=send, actor_id="far@1", capacity=2, backoff_min_s=0.01)
    stop = threading.Event()
    for seq in (0, 1):
        assert inserter.submit(seq, str(seq).encode(), stop=stop)
    assert inserter.wait_idle(stop=stop)
    inserter.close(timeout_s=5)
    log = tmp_path / "actor.log"
    log.write_text("".join(f"2026-01-01 00:00:00,000 actor {r.levelname} {r.name}: "
                           f"{r.getMessage()}\n" for r in caplog.records))
    parsed = net_measure.read_actor_log(log)
    assert parsed.acked == {("far@1", 0), ("far@1", 1)}
    assert parsed.duplicate_acks == 1
    assert inserter.counters.retries == 1


def row(**changes: object) -> net_measure.NetResult:
    fields: dict[str, object] = dict(
        setting="loss-2", injected="2% loss each way", exit_status=0, actor_exits=[0, 0],
        epochs_expected=3, epochs_recorded=[1, 2, 3], episodes=40, acked=38, lost=0,
        stored_records=38, stored_distinct=38, duplicate_acks=1, retries=3, superseded=2,
        unacked=0, lag_p50=2.0, lag_p95=3.0, inserts_per_s=1.5, longest_insert_gap_s=4.0,
        median_epoch_s=8.0, max_epoch_s=9.0, wall_s=60.0, load_before=4.0, load_after=5.0)
    fields.update(changes)
    return net_measure.NetResult(**fields)  # type: ignore[arg-type]


@pytest.mark.parametrize("changes", [
    {"lost": 1}, {"stored_records": 39}, {"epochs_recorded": [1, 2, 2]},
    {"actor_exits": [0, 1]}, {"exit_status": 1}, {"acked": 0},
], ids=["lost", "stored-twice", "epoch-twice", "actor-failed", "run-failed", "nothing-acked"])
def test_a_row_that_broke_a_promise_is_not_ok(changes: dict[str, object]) -> None:
    assert row().ok
    assert not row(**changes).ok


def test_the_report_names_what_was_injected_and_the_verdict() -> None:
    shape = net_faults.Shape()
    cut = net_faults.SETTINGS["partition-acks"]
    table = net_faults.report(
        [row(), row(setting=cut.name, injected=cut.describe(90), lost=2,
                    first_insert_after_heal_s=1.5, next_epoch_after_heal_s=7.0)],
        command="python -m bench.faults.net_faults", shape=shape, note="busy", quick=False)
    assert "| loss-2 | 2% loss each way | 0 / 0,0 | 3 (3) | 38 | 0 | 0 |" in table
    assert ("| partition-acks | cut 90 s towards the actors only |" in table
            and "| 1.5 s / 7 s |" in table and table.rstrip().endswith("| FAILED |"))
    assert "Machine: busy" in table
