"""Hostile input to the clusterer's subscriber of the replay's `replay/inserted` headers."""

from __future__ import annotations

import pytest
from hypothesis import given, settings

from tests.fault.fuzz.oracles import header_verdict
from tests.fault.fuzz.probes import Probe, make_header, mixed, probe_lists
from tests.fault.fuzz.runs import HEADER_MAX_BYTES, HYPOTHESIS, KR, MAX_VALID_HEADERS, VALID
from tests.fault.fuzz.strategies import header_probes
from tests.fault.fuzz.world import World, check_clusterer, check_expect, sent

pytestmark = [pytest.mark.integration, pytest.mark.timeout(420)]


def test_clusterer_header_subscriber_skips_bad_headers(world: World) -> None:
    w = world
    bases = [make_header(s).SerializeToString() for s in range(3)]

    @settings(HYPOTHESIS, max_examples=55)
    @given(probe_lists(mixed(header_probes(), bases, HEADER_MAX_BYTES)))
    def barrage(probes: list[Probe]) -> None:
        sending = []
        for probe in probes:
            verdict = header_verdict(probe.payload)
            check_expect(probe, verdict)
            if verdict == VALID:
                if w.ledger.valid_headers >= MAX_VALID_HEADERS:
                    w.ledger.skipped["replay/inserted (valid)"] += 1
                    continue
                w.ledger.valid_headers += 1
            else:
                w.ledger.header_rejects[verdict] += 1
            sending.append(probe)
            w.puts[KR.inserted].put(probe.payload)
        sent(w, "replay/inserted", sending)

    barrage()
    w.puts[KR.inserted].put(make_header(7).SerializeToString())  # publishes metrics again
    w.ledger.valid_headers += 1
    check_clusterer(w)
