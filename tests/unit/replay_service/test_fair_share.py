"""Fair sharing of the insert capacity between actors (WaitingInserts, in
hercs.replay_service.parked_calls), on the ReplayTable without any transport: while the rate
limiter holds inserts they are admitted round-robin across actor ids, one actor's excess is
refused as a retry and comes back, and an actor alone is admitted exactly as in arrival
order."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import pytest

from hercs.reasons import Disposition, Reason
from tests.unit.replay_service.table_harness import Harness, Recorder, make

# The table's test config: ρ = 2 updates per episode, d = 2·I − S held in [0, 16]. Once the
# limiter is full, each sample call of 8 minibatches makes room for exactly 4 inserts.
ADMITTED_PER_SAMPLE = 4
FAIR_TOLERANCE = 0.8
"""Each actor with inserts waiting gets at least this fraction of its fair share 1/m."""


@dataclass
class SimActor:
    """A client of the table that keeps `depth` inserts in flight (1: an actor's inserter,
    more: a flooding one), resends a refused seq with the same (actor_id, seq), oldest first,
    and sends a new seq only when it has none to resend. It tops up in every `every`-th
    round only (its rate)."""

    name: str
    depth: int
    every: int = 1
    acked: list[int] = field(default_factory=list)
    refused: int = 0
    next_seq: int = 0
    _in_flight: dict[int, Recorder] = field(default_factory=dict)
    _resend: list[int] = field(default_factory=list)

    def collect(self) -> None:
        for seq, waiter in list(self._in_flight.items()):
            if waiter.results:
                assert not waiter.results[0].duplicate, "every seq is stored once"
                self.acked.append(seq)
            elif waiter.failures:
                reason = waiter.failures[0][0]
                assert reason == Reason.ACTOR_QUEUE_FULL, waiter.failures
                assert Reason(reason).disposition is Disposition.RETRY
                self.refused += 1
                self._resend.append(seq)
            else:
                continue
            del self._in_flight[seq]
        self._resend.sort()

    def top_up(self, h: Harness) -> None:
        """Send until `depth` inserts are in flight; each send is answered (acked, refused)
        or parked at once, and `collect` reads the answers."""
        for _ in range(self.depth - len(self._in_flight)):
            if self._resend:
                seq = self._resend.pop(0)
            else:
                seq, self.next_seq = self.next_seq, self.next_seq + 1
            self._in_flight[seq] = h.insert(seq, self.name)

    @property
    def unacked(self) -> list[int]:
        return sorted([*self._in_flight, *self._resend])


def run_rounds(h: Harness, actors: list[SimActor], rounds: int,
               after_round: Callable[[], None] = lambda: None) -> None:
    """Each round: the actors (first to last) collect their answers and top up (those due in
    this round), then the learner samples 8 minibatches, which admits 4 waiting inserts, and
    the actors collect the answers (`after_round` checks them)."""
    for r in range(rounds):
        for actor in actors:
            if r % actor.every == 0:
                actor.top_up(h)
        h.sample(8)
        for actor in actors:
            actor.collect()
        after_round()


def fill_limiter(h: Harness) -> None:
    """8 inserts of a filler actor: d = 16, the limiter holds the next insert."""
    for seq in range(8):
        assert h.insert(seq, "filler").results
    assert not h.table.limiter.can_insert()


def shares(actors: list[SimActor], since: dict[str, int]) -> dict[str, float]:
    counts = {a.name: len(a.acked) - since[a.name] for a in actors}
    total = sum(counts.values())
    return {name: count / total for name, count in counts.items()}


@pytest.mark.parametrize("flood_depth", [4, 12, 40], ids=["depth4", "depth12", "depth40"])
def test_one_flooding_and_three_normal_actors_each_get_a_quarter(flood_depth: int) -> None:
    h = make()  # replay.waiting_inserts_per_actor = 4 (the default)
    fill_limiter(h)
    flooder = SimActor("flooder", depth=flood_depth)
    normal = [SimActor(f"normal-{i}", depth=1) for i in range(3)]
    actors = [flooder, *normal]  # the flooder sends first in every round: the others' worst case
    run_rounds(h, actors, 10)  # warm-up
    since = {a.name: len(a.acked) for a in actors}
    run_rounds(h, actors, 50)
    share = shares(actors, since)
    fair = 1 / len(actors)
    for actor in actors:
        assert share[actor.name] >= FAIR_TOLERANCE * fair, share
    st = h.table.status()
    assert st.inserts == 8 + sum(len(a.acked) for a in actors), "every ack is a stored episode"
    waiting_flood = st.inserts_waiting - sum(len(a.unacked) for a in normal)
    assert waiting_flood <= 4, "at most replay.waiting_inserts_per_actor of one actor wait"
    if flood_depth > 4:
        assert flooder.refused > 0 and st.rejects == {"actor_queue_full": flooder.refused}
    # nothing is lost: the flooder's acked seqs are distinct, and with what is still in
    # flight or due for a resend they are exactly the seqs it ever sent
    assert len(set(flooder.acked)) == len(flooder.acked)
    assert sorted(flooder.acked + flooder.unacked) == list(range(flooder.next_seq))


def test_in_arrival_order_the_flooder_takes_the_capacity() -> None:
    """The gap fair sharing closes (replay.waiting_inserts_per_actor=0: the replay before)."""
    h = make("replay.waiting_inserts_per_actor=0")
    fill_limiter(h)
    flooder = SimActor("flooder", depth=12)
    normal = [SimActor(f"normal-{i}", depth=1) for i in range(3)]
    actors = [flooder, *normal]
    run_rounds(h, actors, 10)
    since = {a.name: len(a.acked) for a in actors}
    run_rounds(h, actors, 50)
    share = shares(actors, since)
    assert share["flooder"] > 0.6, share
    for actor in normal:
        assert share[actor.name] < 0.5 / len(actors), share
    assert flooder.refused == 0 and h.table.status().rejects == {}


def test_a_normal_actor_below_its_share_gets_every_insert_admitted_within_one_round() -> None:
    """An actor that sends one insert every other round (half its fair share) is admitted in
    the round it sends, however many inserts the flooder has waiting: its insert waits for at
    most m − 1 = 3 other admissions, and a round admits 4."""
    h = make()
    fill_limiter(h)
    flooder = SimActor("flooder", depth=40)
    normal = [SimActor(f"normal-{i}", depth=1, every=2) for i in range(3)]
    actors = [flooder, *normal]
    rounds = 40

    def each_admitted_in_its_round() -> None:
        assert all(actor.unacked == [] for actor in normal)

    run_rounds(h, actors, rounds, each_admitted_in_its_round)
    for actor in normal:
        assert len(actor.acked) == rounds // 2
    assert len(flooder.acked) == ADMITTED_PER_SAMPLE * rounds - 3 * (rounds // 2), \
        "the flooder gets all the rest"


def test_one_actor_alone_is_admitted_as_in_arrival_order() -> None:
    """Fair sharing changes nothing for a lone actor, however many inserts it keeps in flight:
    the same seqs are stored under the same ids, 4 per sample call, as in arrival order."""
    stored: dict[str, list[tuple[int, int]]] = {}
    for setting in ("4", "0"):
        h = make(f"replay.waiting_inserts_per_actor={setting}")
        alone = SimActor("alone", depth=12)
        run_rounds(h, [alone], 30)
        assert len(alone.acked) == 8 + ADMITTED_PER_SAMPLE * 30, "the fill, then 4 per call"
        stored[setting] = [(episode_id, msg.seq) for episode_id, msg in h.log.episodes]
    assert stored["4"] == stored["0"]
    assert [seq for _, seq in stored["4"]] == list(range(len(stored["4"])))


def test_round_robin_order_and_the_bound_on_one_actors_waiting_inserts() -> None:
    h = make()
    fill_limiter(h)
    for seq in range(4):
        h.insert(seq, "a")
    refused = h.insert(4, "a")
    assert refused.failures[0][0] == Reason.ACTOR_QUEUE_FULL and not refused.results
    assert "replay.waiting_inserts_per_actor=4" in refused.failures[0][1]
    joined = h.insert(3, "a")  # a retry of a waiting seq joins it, even at the bound
    assert not joined.failures
    for actor in ("b", "c"):
        h.insert(0, actor)
    h.journal.clear()
    h.sample(8)
    h.sample(8)
    acked = [line for line in h.journal if line.startswith("done insert")]
    assert acked == ["done insert a/0", "done insert b/0", "done insert c/0",
                     "done insert a/1", "done insert a/2", "done insert a/3",
                     "done insert a/3"], "a's seq 3 twice: the joined retry is acked with it"
    assert joined.results[0].duplicate
    again = h.insert(4, "a")  # nothing of a waits now: its resend is taken (and admitted)
    assert again.results and not again.results[0].duplicate
    assert [m.seq for _, m in h.log.episodes[8:]] == [0, 0, 0, 1, 2, 3, 4]
    st = h.table.status()
    assert st.rejects == {"actor_queue_full": 1} and len(h.log.episodes) == 8 + 7


def test_expired_inserts_leave_the_ring_and_the_rest_keep_their_turns() -> None:
    h = make()
    fill_limiter(h)
    a0 = h.insert(0, "a", timeout_s=5.0)
    a1 = h.insert(1, "a", timeout_s=60.0)
    b0 = h.insert(0, "b", timeout_s=5.0)
    c0 = h.insert(0, "c", timeout_s=60.0)
    h.clock.now += 5.0
    assert h.table.expire() == 2
    assert a0.failures[0][0] == b0.failures[0][0] == Reason.EXPIRED
    assert h.table.status().inserts_waiting == 2
    h.journal.clear()
    h.sample(8)
    assert [line for line in h.journal if line.startswith("done insert")] == [
        "done insert a/1", "done insert c/0"]
    assert a1.results and c0.results
