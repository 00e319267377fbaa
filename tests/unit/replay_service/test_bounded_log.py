"""A bounded episode log (`replay.log_max_bytes`) under the real replay table and MCAP writer:
the log stays under its bound plus one segment while the buffer evicts, and a replay recovered
from it is the replay recovered from the same log kept whole (same buffer and slots, dedup
keys, counts, normalisers, next batches). Synthetic Reach episodes, no learner, 20-episode
buffer in 5-episode segments."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.replay_service.builder import ReplayBuilder
from hercs.replay_service.lockstep import LockstepAdmission
from hercs.replay_service.table import ReplayTable, SampleCall, Stored
from hercs.rl.cluster_model import ClusterModel
from hercs.run.runlog import (
    EpisodeLogError,
    RecoveringLogWriter,
    latest_replay_state,
    read_cluster_models,
    read_episode_messages,
    segment_paths,
)
from hercs.wire.codec import (
    cluster_model_to_msg,
    episode_to_msg,
    msg_to_episode,
    msg_to_replay_state,
)
from hercs.wire.episode import EpisodeData
from hercs.wire.served import ServedBatch

RUN, TASK = "t", "reach"
EPISODES = 120
CAPACITY = 20
UNBOUNDED = 10**15
"""A bound no test log reaches: the log is split and saves states, but nothing is deleted."""


class Answer:
    def __init__(self) -> None:
        self.result: object = None

    def done(self, result: object) -> None:
        self.result = result

    def fail(self, reason: str, detail: str) -> None:
        raise AssertionError(f"refused: {reason}: {detail}")


def config(max_bytes: int, *extra: str) -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        f"task.name={TASK}", "run.method=her-cs", "cluster.k=2", f"run.name={RUN}",
        f"replay.buffer_transitions={CAPACITY * 50}", "replay.free_run=true",
        "training.max_policy_lag=-1", f"replay.log_max_bytes={max_bytes}", *extra])


def episodes(cfg: HercsConfig, n: int = EPISODES) -> list[EpisodeData]:
    spec = cfg.task.spec
    per_cycle = cfg.training.episodes_per_cycle
    return [dataclasses.replace(random_episode(spec, np.random.default_rng(i), actor_id="a",
                                               seq=i), policy_version=i // per_cycle)
            for i in range(n)]


def open_table(cfg: HercsConfig, run_dir: Path, seed: int = 0
               ) -> tuple[ReplayTable, RecoveringLogWriter]:
    """A replay table on `run_dir`'s log, recovered from it as the replay service does."""
    log, recovered = RecoveringLogWriter.open(
        run_dir, run=RUN, task=TASK, scene=True,
        segment_episodes=cfg.replay.log_segment_episodes(cfg.capacity_episodes),
        max_bytes=cfg.replay.log_max_bytes)
    table = ReplayBuilder(cfg).table(rng=np.random.default_rng(seed), log=log)
    state = recovered.replay_state
    table.recover(((i, msg_to_episode(msg)) for i, msg in recovered),
                  state=None if state is None else msg_to_replay_state(state))
    # the episodes carry a learner's weights versions (one a cycle), and no learner asks here
    table.lags.announced(1 << 30)
    return table, log


def log_bytes(run_dir: Path) -> int:
    return sum(p.stat().st_size for p in segment_paths(run_dir))


def run(cfg: HercsConfig, run_dir: Path, data: list[EpisodeData]) -> list[int]:
    """Insert `data` (a cluster model adopted after the 8th); returns the log's size after
    each insert, once the log's upkeep (closing, pruning) is done."""
    table, log = open_table(cfg, run_dir)
    sizes = []
    try:
        for i, episode in enumerate(data):
            answer = Answer()
            table.insert(episode, record=episode_to_msg(episode, run=RUN, task=TASK),
                         waiter=answer)
            assert isinstance(answer.result, Stored) and answer.result.episode_id == i
            if i == 7:
                model = ClusterModel(version=1, centroids=np.array([[-.5] * 3, [.5] * 3]),
                                     n_goals=8, failures_seen=8)
                table.adopt_cluster_model(model, cluster_model_to_msg(model))
            log.flush_upkeep()
            sizes.append(log_bytes(run_dir))
    finally:
        log.close()
    return sizes


STORE_FIELDS = ("obs", "ag", "g", "actions", "episode_id", "actor_id", "seq", "success",
                "final_ag", "energy", "cluster", "policy_version", "moved")


def assert_same_buffer(a: ReplayTable, b: ReplayTable) -> None:
    for name in STORE_FIELDS:
        assert np.array_equal(getattr(a.store, name), getattr(b.store, name)), name
    assert a.store.num_inserted == b.store.num_inserted
    assert list(a._seen.items()) == list(b._seen.items()), "the same retries are dedup'd"
    assert (a.inserts, a.env_steps, a.failures) == (b.inserts, b.env_steps, b.failures)
    assert np.array_equal(a.clusterer_state().failed_goals, b.clusterer_state().failed_goals)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[HercsConfig, Path,
                                                                    list[int]]]:
    """The same 120 episodes logged with a small bound, with no deletion, and unsplit."""
    root = tmp_path_factory.mktemp("logs")
    out = {}
    # the bound: what resume needs here is ~1.5 buffers ≈ 30 episodes ≈ 0.25 MB; 0.4 MB keeps
    # a little more than that
    for name, max_bytes in (("bounded", 400_000), ("kept", UNBOUNDED), ("unsplit", -1)):
        cfg = config(max_bytes)
        out[name] = (cfg, root / name, run(cfg, root / name, episodes(cfg)))
    return out


def test_the_log_stays_under_its_bound_plus_one_segment(runs) -> None:
    cfg, bounded_dir, sizes = runs["bounded"]
    _, kept_dir, kept_sizes = runs["kept"]
    segments = segment_paths(kept_dir)[:-1]
    slack = max(p.stat().st_size for p in segments)  # one closed segment, the largest
    assert len(segments) == EPISODES // 5, "a segment every 5 episodes"
    assert max(sizes) <= cfg.replay.log_max_bytes + slack, (max(sizes), slack)
    assert kept_sizes[-1] > 3 * cfg.replay.log_max_bytes, "the bound did matter"
    first_kept = next(read_episode_messages(bounded_dir))[0]
    assert first_kept > 0, "old segments were deleted"
    assert first_kept <= EPISODES - CAPACITY, "every episode of the buffer is kept"
    # the model logged after episode 7 went with its segment; the newest state carries it
    assert list(read_cluster_models(bounded_dir)) == []


def test_a_replay_resumed_from_a_bounded_log_is_the_one_resumed_from_the_whole_log(
        runs) -> None:
    (cfg, bounded_dir, _), (_, kept_dir, _) = runs["bounded"], runs["kept"]
    a, log_a = open_table(cfg, bounded_dir, seed=7)
    b, log_b = open_table(cfg, kept_dir, seed=7)
    try:
        assert_same_buffer(a, b)
        assert a.store.size == CAPACITY
        assert list(a.store.episode_id) == [EPISODES - CAPACITY + (i - EPISODES) % CAPACITY
                                                 for i in range(CAPACITY)]
        for name in ("sum", "sumsq", "count"):  # exactly the running replay's statistics
            assert np.array_equal(a.normalizers.o_norm.state_dict()[name],
                                  b.normalizers.o_norm.state_dict()[name])
            assert np.array_equal(a.normalizers.g_norm.state_dict()[name],
                                  b.normalizers.g_norm.state_dict()[name])
        assert (a.limiter.inserts, a.limiter.samples) == (b.limiter.inserts, b.limiter.samples)
        # the same buffer, index and generator state: the next batches are the same
        answers = [Answer(), Answer()]
        for table, answer in zip((a, b), answers, strict=True):
            table.sample(SampleCall(num_minibatches=2, batch_size=16), waiter=answer)
        got_a, got_b = (answer.result for answer in answers)
        assert isinstance(got_a, ServedBatch) and isinstance(got_b, ServedBatch)
        for mb_a, mb_b in zip(got_a.minibatches, got_b.minibatches, strict=True):
            assert np.array_equal(mb_a.o, mb_b.o) and np.array_equal(mb_a.g, mb_b.g)
    finally:
        log_a.close()
        log_b.close()
    saved = latest_replay_state(segment_paths(bounded_dir))
    assert saved is not None
    state = msg_to_replay_state(saved)
    assert state.cluster_model is not None and state.cluster_model.version == 1


def test_the_buffer_is_the_one_an_unsplit_log_resumes_to(runs) -> None:
    (cfg, bounded_dir, _), (_, unsplit_dir, _) = runs["bounded"], runs["unsplit"]
    assert len(segment_paths(unsplit_dir)) == 1, "-1 keeps one segment per replay start"
    a, log_a = open_table(cfg, bounded_dir)
    b, log_b = open_table(cfg, unsplit_dir)
    try:
        assert_same_buffer(a, b)
        assert a.normalizers.o_norm.count == b.normalizers.o_norm.count
    finally:
        log_a.close()
        log_b.close()


@pytest.mark.parametrize("extra", [("replay.eviction=random",),
                                   ("training.schedule=lockstep", "replay.free_run=false")],
                         ids=["random-eviction", "lockstep"])
def test_resume_is_exact_with_random_eviction_and_in_lockstep(tmp_path: Path,
                                                              extra: tuple[str, ...]) -> None:
    """Random eviction keeps an episode for ~capacity·ln(capacity) inserts, so less of its
    log goes; lockstep's per-version counts come back from the state."""
    bounded, kept = config(0, *extra), config(UNBOUNDED, *extra)
    run(bounded, tmp_path / "bounded", episodes(bounded, 200))
    run(kept, tmp_path / "kept", episodes(kept, 200))
    assert next(read_episode_messages(tmp_path / "bounded"))[0] > 0, "old segments were deleted"
    a, log_a = open_table(bounded, tmp_path / "bounded")
    b, log_b = open_table(kept, tmp_path / "kept")
    try:
        assert_same_buffer(a, b)
        if isinstance(a.admission, LockstepAdmission):
            assert isinstance(b.admission, LockstepAdmission)
            assert +a.admission.stored == +b.admission.stored and len(+a.admission.stored) == 50
            assert a.admission.requested == b.admission.requested == 49
    finally:
        log_a.close()
        log_b.close()
    shutil.rmtree(tmp_path)


def test_restarts_do_not_put_off_the_next_state(tmp_path: Path) -> None:
    """A replay restarted every 3 episodes (fewer than a segment's 5) still saves a state
    once 5 episodes have been logged since the last one, so its log is pruned all the same,
    and each restart resumes the buffer the log kept whole would give."""
    bounded, kept = config(0), config(UNBOUNDED)
    data = episodes(bounded, 60)
    for start in range(0, 60, 3):
        for cfg, name in ((bounded, "bounded"), (kept, "kept")):
            table, log = open_table(cfg, tmp_path / name)
            try:
                for i in range(start, start + 3):
                    answer = Answer()
                    table.insert(data[i], record=episode_to_msg(data[i], run=RUN, task=TASK),
                                 waiter=answer)
                    assert isinstance(answer.result, Stored) and answer.result.episode_id == i
            finally:
                log.close()
    saved = latest_replay_state(segment_paths(tmp_path / "bounded"))
    assert saved is not None and saved.next_episode_id >= 60 - 5
    assert next(read_episode_messages(tmp_path / "bounded"))[0] >= 60 - CAPACITY - 2 * 5
    a, log_a = open_table(bounded, tmp_path / "bounded")
    b, log_b = open_table(kept, tmp_path / "kept")
    try:
        assert_same_buffer(a, b)
    finally:
        log_a.close()
        log_b.close()


def test_a_bigger_buffer_than_the_log_kept_is_refused_with_the_reason(tmp_path: Path) -> None:
    cfg = config(0)
    run(cfg, tmp_path / "log", episodes(cfg, 40))
    bigger = config(0, f"replay.buffer_transitions={2 * CAPACITY * 50}")
    with pytest.raises(EpisodeLogError, match=r"written with a smaller replay\.buffer_trans"):
        open_table(bigger, tmp_path / "log")


@pytest.mark.parametrize("task", ["push", "PointMaze_UMaze-v3", "HandReach-v3",
                                  "HandManipulateBlock-v1"])
def test_a_replay_restores_from_its_saved_state_on_every_task(tmp_path: Path,
                                                              task: str) -> None:
    """Replay state written (a split log), replay gone, replay restored from that state and
    the log's tail: on a Fetch task, a maze (no energy), a hand (joint-space goals) and an
    in-hand object, the restored buffer's energies are those computed at insert (a restore
    used to compute them without the task's energy kind, and raised on the non-Fetch ones)."""
    spec_steps = apply_overrides(HercsConfig(), [f"task.name={task}"]).task.spec.episode_steps
    cfg = apply_overrides(HercsConfig(), [
        f"task.name={task}", "run.method=her-cs", f"run.name={RUN}",
        f"replay.buffer_transitions={CAPACITY * spec_steps}", "replay.free_run=true",
        "training.max_policy_lag=-1", f"replay.log_max_bytes={UNBOUNDED}"])

    def opened(seed: int) -> tuple[ReplayTable, RecoveringLogWriter, object]:
        log, recovered = RecoveringLogWriter.open(
            tmp_path, run=RUN, task=task, scene=False,
            segment_episodes=cfg.replay.log_segment_episodes(cfg.capacity_episodes),
            max_bytes=cfg.replay.log_max_bytes)
        table = ReplayBuilder(cfg).table(rng=np.random.default_rng(seed), log=log)
        state = recovered.replay_state
        table.recover(((i, msg_to_episode(msg)) for i, msg in recovered),
                      state=None if state is None else msg_to_replay_state(state))
        table.lags.announced(1 << 30)  # as in open_table: no learner asks here
        return table, log, state

    first, log, state = opened(0)
    assert state is None
    try:
        for episode in episodes(cfg, 2 * CAPACITY + 3):
            answer = Answer()
            first.insert(episode, record=episode_to_msg(episode, run=RUN, task=task),
                         waiter=answer)
            assert isinstance(answer.result, Stored), answer.result
            log.flush_upkeep()
        at_insert = first.store.energy.copy()
    finally:
        log.close()
    again, log, state = opened(1)
    try:
        assert state is not None, "the log saved a replay state to restore from"
        np.testing.assert_array_equal(again.store.energy, at_insert)
        assert_same_buffer(first, again)
        if first.spec.energy != "none":
            assert at_insert.any(), "random episodes move their goals: some energy"
    finally:
        log.close()
