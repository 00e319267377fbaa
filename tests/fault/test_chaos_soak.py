"""The chaos soak's quick mode end to end (bench.faults.chaos): a FetchReach run over mutual TLS
whose one actor, on another "host", is SIGKILLed and restarted, then cut off for 12 s; nothing
acked is lost or stored twice and nothing of the faults is left. Needs root, iproute2 and
iptables (`make netfault-tools`); otherwise skipped with the reason. What is asserted and how
long it takes: docs/FAULTS.md, "The chaos soak".
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from bench.faults import chaos
from bench.faults.chaos_plan import QUICK_PLAN
from bench.faults.chaos_state import QUICK_SHAPE
from bench.faults.netns import make_host, problem

pytestmark = [pytest.mark.integration, pytest.mark.full, pytest.mark.timeout(420)]


def test_a_run_rides_out_a_killed_actor_and_a_cut_and_loses_nothing(tmp_path: Path) -> None:
    if (why := problem(chaos.SUBNET)) is not None:
        pytest.skip(why)
    record = chaos.soak(QUICK_SHAPE, chaos_seed=1, plan=QUICK_PLAN, work=tmp_path,
                        committed=None, quick=True)
    result = record["result"]
    print(record["injections"], result)
    assert record["up_exits"] == [0] and result["actor_exits"] == [0], result["notes"]
    assert result["epochs_recorded"] == [1, 2, 3, 4, 5], "every epoch once"
    assert result["acked"] > 0 and result["lost"] == 0, "every acked episode is in the log"
    assert result["stored_twice"] == 0
    assert len(record["injections"]) == 2, "each injection is held until its epoch"
    kill, cut = record["injections"]
    assert (kill["kind"], kill["outcome"], cut["kind"]) == ("kill", "done", "cut")
    assert cut["healed_at_s"] >= cut["at_s"] + 12.0
    incarnations = [(a["ident"], a["killed_by"]) for a in record["actor_incarnations"]]
    assert incarnations.count((kill["target"], "schedule")) == 1
    assert incarnations.count((kill["target"], "")) == 1, "started again once"
    assert kill["next_insert_s"] is not None, "the new incarnation inserted"
    assert cut["next_insert_s"] is not None, "the cut actor inserted after the heal"
    assert record["ok"]
    # nothing of the faults is left: the namespaces, their links, the iptables chains
    ours = [make_host(i + 1, subnet=chaos.SUBNET) for i in range(QUICK_SHAPE.actors)]
    netns = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    rules = subprocess.run(["iptables", "-w", "-S"], capture_output=True, text=True).stdout
    assert problem(chaos.SUBNET) is None, "the soak's subnet is free again"
    for host in ours:
        assert host.name not in netns and host.chain not in rules
