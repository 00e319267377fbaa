"""Hostile input to the clusterer's subscriber of the replay's `replay/inserted` headers."""

from __future__ import annotations

import pytest

from tests.fault.fuzz.oracles import header_verdict
from tests.fault.fuzz.probes import Probe, make_header, run_barrage
from tests.fault.fuzz.runs import HEADER_MAX_BYTES, KR, MAX_VALID_HEADERS, VALID
from tests.fault.fuzz.strategies import header_probes
from tests.fault.fuzz.world import World, capped_verdicts, check_clusterer, sent

pytestmark = [pytest.mark.integration, pytest.mark.timeout(420)]


def test_clusterer_header_subscriber_skips_bad_headers(world: World) -> None:
    w = world
    bases = [make_header(s).SerializeToString() for s in range(3)]

    def barrage(probes: list[Probe]) -> None:
        sending = capped_verdicts(w, probes, header_verdict, "replay/inserted",
                                  MAX_VALID_HEADERS, "replay/inserted (valid)")
        for probe, verdict in sending:
            if verdict != VALID:
                w.ledger.header_rejects[verdict] += 1
            w.puts[KR.inserted].put(probe.payload)
        sent(w, "replay/inserted", [probe for probe, _ in sending])

    run_barrage(barrage, header_probes(), bases, HEADER_MAX_BYTES, examples=55)
    w.puts[KR.inserted].put(make_header(7).SerializeToString())  # publishes metrics again
    w.ledger.valid_sent["replay/inserted"] += 1
    check_clusterer(w)
