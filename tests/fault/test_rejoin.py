"""A client on another "host" comes back after each of repeated cuts of its link, over
mutual TLS (bench.faults.rejoin): cuts of 2, 12, 30 and 5 s (below, around and well beyond Zenoh's
10 s lease), each followed by an answered request within `REJOIN_BOUND_S` of the heal.

Needs root, iproute2 and iptables (`make netfault-tools`); otherwise skipped with the reason.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from bench.faults import rejoin
from bench.faults.netns import hosts, problem
from hercs.apps.deploy.certs import make_certs

pytestmark = [pytest.mark.integration, pytest.mark.full, pytest.mark.timeout(400)]

CUTS_S = (2.0, 12.0, 30.0, 5.0)


def test_a_client_is_answered_again_within_the_bound_after_every_cut(tmp_path: Path) -> None:
    if (why := problem(rejoin.SUBNET)) is not None:
        pytest.skip(why)
    with hosts(1, subnet=rejoin.SUBNET) as (host,):
        name, chain = host.name, host.chain
        make_certs(tmp_path, hosts=[host.host_ip])
        cuts = rejoin.probe(CUTS_S, host=host, certs=tmp_path)
    print([(c.length_s, c.rejoined_s) for c in cuts])
    assert [c.length_s for c in cuts] == list(CUTS_S)
    for cut in cuts:
        assert cut.healed_at - cut.cut_at >= cut.length_s
        assert cut.rejoined_s is not None and cut.rejoined_s <= rejoin.REJOIN_BOUND_S, cut
    netns = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    rules = subprocess.run(["iptables", "-w", "-S"], capture_output=True, text=True).stdout
    assert name not in netns and chain not in rules
