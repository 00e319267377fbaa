"""`hercs actor` as a real process against a router on loopback.

The test plays the replay and the learner: it serves `config` (the run's resolved YAML, as the
replay does), answers `replay/insert` (acking, or deliberately not), and publishes `Weights`.
No sleeps stand in for synchronisation: every wait is on a queue with a timeout or the
process exit.
"""

from __future__ import annotations

import queue
import subprocess
import threading
import time
from collections import Counter
from datetime import datetime
from pathlib import Path

import pytest
import yaml

from hercs.actors.inserter import Inserter
from hercs.config import HercsConfig, apply_overrides
from hercs.net.transport import PendingReply, Transport, TransportError
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.reasons import Reason
from hercs.rl.policy import Policy
from hercs.wire.codec import msg_to_array, weights_to_msg
from tests.integration.services import WAIT_S, OpenClient, OpenRunSide, start_service, wait_for

pytestmark = pytest.mark.integration



# ---- the actor

RUN = "t-actor"


def run_config(endpoint: str, envs_per_process: int = 1) -> HercsConfig:
    """What the replay serves: the whole resolved config of the run."""
    return apply_overrides(HercsConfig(), [
        f"run.name={RUN}", "run.method=her", "task.name=reach", "ddpg.hidden_size=64",
        "actor.insert_timeout_s=3.0", f"transport.connect=[{endpoint}]",  # a held insert
        # times out and is retried; an ack a loaded machine delays must not (it would be acked
        # twice)
        f"actor.envs_per_process={envs_per_process}",
    ])


def local_config(endpoint: str) -> HercsConfig:
    """What `hercs actor --connect ENDPOINT --run RUN` knows: run name and endpoint only (the
    task default, push, must be replaced by the run's)."""
    return apply_overrides(HercsConfig(), [f"run.name={RUN}", f"transport.connect=[{endpoint}]"])


def weights_msg(policy: Policy, *, version: int) -> bytes:
    w = policy.weights()
    return weights_to_msg(version=version, actor_params=w.actor, o_stats=w.o_stats,
                          g_stats=w.g_stats, epoch=1, evaluate=False).SerializeToString()


class FakeReplay:
    """`replay/insert` that acks, except: seq 1's first attempt is never answered (a timeout),
    seq 2's first is answered `unavailable`, seq 3 is rejected `bad_shape` (to be dropped).
    Once `closing` is set, every attempt is answered `unavailable`, as a replay shutting down
    answers, and recorded in `closing_attempts`."""

    def __init__(self, transport: Transport, keys: RunKeys) -> None:
        self.attempts: Counter[int] = Counter()
        self.acks: Counter[int] = Counter()
        self.acked: queue.Queue[pb.Episode] = queue.Queue()
        self.held: list[PendingReply] = []
        self.closing = threading.Event()
        self.closing_attempts: list[tuple[float, int]] = []
        """(wall time, seq) of each attempt answered while closing."""
        self._lock = threading.Lock()
        transport.serve_deferred(keys.insert, self.handle)

    def handle(self, pending: PendingReply) -> None:
        episode = pb.Episode.FromString(pending.payload)
        if self.closing.is_set():
            with self._lock:
                self.closing_attempts.append((time.time(), episode.seq))
            pending.reply_error(Reason.UNAVAILABLE, "replay closing")
            return
        with self._lock:
            self.attempts[episode.seq] += 1
            first = self.attempts[episode.seq] == 1
            duplicate = self.acks[episode.seq] > 0
        if first and episode.seq == 1:
            self.held.append(pending)  # never answered: the actor times out and retries
            return
        if first and episode.seq == 2:
            pending.reply_error(Reason.UNAVAILABLE, "replay restarting")
            return
        if episode.seq == 3:
            pending.reply_error(Reason.BAD_SHAPE, "Episode.obs: the test rejects seq 3")
            return
        with self._lock:
            self.acks[episode.seq] += 1
        pending.reply(pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id=episode.actor_id,
                                   seq=episode.seq, episode_id=episode.seq,
                                   duplicate=duplicate).SerializeToString())
        self.acked.put(episode)


@pytest.mark.parametrize("envs_per_process", [1, 3])
def test_actor_joins_run_inserts_at_least_once_and_adopts_weights(
    run_side: OpenRunSide, endpoint: str, envs_per_process: int,
) -> None:
    """With one env, and with three stepped side by side (`actor.envs_per_process`): the same
    delivery contract, seqs in order, one policy version per episode."""
    served = run_config(endpoint, envs_per_process)
    run = run_side(RUN)
    side, keys = run.transport, run.keys
    metrics = run.metrics("actor")
    replay = FakeReplay(side, keys)

    actor = run.start("actor", local_config(endpoint), "a0")
    # The run's config is served only now, and its first query is refused: the actor must
    # keep asking.
    config_queries: list[PendingReply] = []

    def serve_config(pending: PendingReply) -> None:
        config_queries.append(pending)
        if len(config_queries) == 1:
            pending.reply_error(Reason.UNAVAILABLE, "replay still loading its log")
        else:
            pending.reply(yaml.safe_dump(served.to_dict()).encode())

    side.serve_deferred(keys.config, serve_config)

    episodes: list[pb.Episode] = []

    def next_acked() -> pb.Episode:
        episodes.append(replay.acked.get(timeout=WAIT_S))
        return episodes[-1]

    while next_acked().seq < 5:
        pass
    assert {e.policy_version for e in episodes} == {-1}
    first = episodes[0]
    assert (first.run, first.task) == (RUN, "reach"), "the run's config"
    assert first.actor_id.startswith("a0@"), "the id plus this process's incarnation"
    assert {e.actor_id for e in episodes} == {first.actor_id}
    assert tuple(msg_to_array(first.obs).shape) == (51, served.task.spec.obs_dim)
    goals = {tuple(msg_to_array(e.g)[0].tolist()) for e in episodes[:3]}
    assert len(goals) == 3, "each env (and each reset) draws its own goal"

    learner = side.publisher(keys.weights, latest=True, block=True)  # as the learner
    learner.put(b"\x08\x01 not a Weights message")  # ignored, the actor carries on
    policy = Policy(spec=served.task.spec, config=served.ddpg, seed=11)
    learner.put(weights_msg(policy, version=7))
    while next_acked().policy_version != 7:
        pass
    for _ in range(3):
        assert next_acked().policy_version == 7, "a newer policy is never replaced by an older"

    assert len(config_queries) == 2
    values = wait_for(metrics, lambda m: m["weights_rejected"] >= 1 and m["dropped"] == 1
                      and m["policy_version"] == 7, "metrics after the weights")
    assert values["retries"] >= 2 and values["env_steps"] >= 50 * values["episodes"] > 0
    run.stop_cleanly(actor, "actor", "a0")

    acked = set(replay.acks)
    assert acked == set(range(max(acked) + 1)) - {3}, "every seq but the rejected one is acked"
    assert set(replay.acks.values()) == {1}, "each seq acked exactly once"
    assert replay.attempts[1] == replay.attempts[2] == 2, "same (actor, seq) retried once"
    assert replay.attempts[3] == 1, "a validation reject is not retried"
    assert [e.seq for e in episodes] == sorted(e.seq for e in episodes)


def test_a_remote_actor_exits_by_itself_when_the_learner_says_the_run_is_finished(
    open_client: OpenClient, endpoint: str, tmp_path: Path, procs: list[subprocess.Popen],
) -> None:
    served = run_config(endpoint)
    keys = RunKeys(RUN)
    side = open_client()
    side.serve(keys.config, lambda _: yaml.safe_dump(served.to_dict()).encode())
    replay = FakeReplay(side, keys)
    procs.append(start_service("actor", local_config(endpoint), "a1", tmp_path))
    replay.acked.get(timeout=WAIT_S)  # it is rolling out
    progress = side.publisher(keys.progress, latest=True, block=True)  # as the learner
    progress.put(pb.RunProgress(schema_version=SCHEMA_VERSION, epoch=2, epochs=3,
                                finished=False).SerializeToString())
    progress.put(b"garbage is ignored")
    replay.acked.get(timeout=WAIT_S)  # still rolling out: the run is not finished
    assert procs[0].poll() is None
    replay.closing.set()  # from here the replay refuses inserts, as one shutting down does
    progress.put(pb.RunProgress(schema_version=SCHEMA_VERSION, epoch=3, epochs=3,
                                finished=True).SerializeToString())
    assert procs[0].wait(timeout=WAIT_S) == 0
    # The run is over: an episode refused once the actor knows it is given up, never retried
    # (a retry would keep the process alive past its run; under Slurm its step would end
    # `CANCELLED`). Before the finished message reaches it (a loaded machine may take a
    # while), the actor rightly retries an `unavailable`: only attempts after its own log
    # line count.
    line = next(line for line in (tmp_path / "actor.log").read_text().splitlines()
                if "finished (3 epochs); stopping" in line)
    knew_at = datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
    late = Counter(seq for at, seq in replay.closing_attempts if at > knew_at)
    assert max(late.values(), default=1) == 1, (late, replay.closing_attempts, knew_at)


def test_an_inserter_of_capacity_0_holds_the_next_episode_until_the_last_is_acked() -> None:
    """`actor.insert_queue=0`: nothing waits behind the delivery in flight."""
    entered, release = threading.Event(), threading.Event()

    def held_send(payload: bytes) -> bytes:
        entered.set()
        release.wait(WAIT_S)
        return pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id="a",
                            seq=int(payload.decode()), episode_id=0).SerializeToString()

    inserter = Inserter(send=held_send, actor_id="a", capacity=0)
    running, stopped = threading.Event(), threading.Event()
    stopped.set()
    assert inserter.submit(0, b"0", stop=running)
    assert entered.wait(WAIT_S)
    assert not inserter.submit(1, b"1", stop=stopped), "one in flight: the next is not taken"
    assert inserter.queued == 0
    release.set()
    assert inserter.submit(1, b"1", stop=running), "taken once the first is acked"
    assert inserter.wait_idle(stop=running)
    assert inserter.counters.acked == 2
    inserter.close(timeout_s=1.0)
    assert inserter.join(WAIT_S)


def test_inserter_backpressure_then_gives_up_unacked_episodes_at_close() -> None:
    """The replay holds the in-flight insert (rate limiter): the queue fills, `submit` refuses
    once stopped, and `close` gives up what was never acked within its flush time."""
    entered, release = threading.Event(), threading.Event()

    def held_send(payload: bytes) -> bytes:
        entered.set()
        release.wait(WAIT_S)  # the transport closing ends a held request with this error
        raise TransportError("request to 'replay/insert': the session closed while it waited")

    inserter = Inserter(send=held_send, actor_id="a", capacity=2)
    running, stopped = threading.Event(), threading.Event()
    stopped.set()
    assert inserter.submit(0, b"e0", stop=running)
    assert entered.wait(WAIT_S)
    assert inserter.submit(1, b"e1", stop=running) and inserter.submit(2, b"e2", stop=running)
    assert inserter.queued == 2
    assert not inserter.submit(3, b"e3", stop=stopped), "full queue + stop: not queued"

    inserter.close(timeout_s=0.1)
    release.set()
    assert inserter.join(WAIT_S)
    c = inserter.counters
    assert (c.acked, c.dropped, c.abandoned, c.retries) == (0, 0, 3, 0)
