"""One finite, huge episode sent over TLS with a valid actor certificate, at the current
weights version, cannot poison a run (issue 57): a FetchReach run given a 3e38-valued episode
after its second epoch refuses it `implausible`, says so on its epoch line, and still learns
as the unpoisoned run of tests/learning/test_reach_learns.py does (≥ 0.9 in one of its last
three epochs); before, the same episode took such a run from 1.00 to 0.00 for good."""

from __future__ import annotations

import csv
import queue
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.apps.deploy.certs import make_certs
from hercs.apps.launch.router import free_port
from hercs.config import SecurityConfig, load_yaml
from hercs.net.security import zenoh_settings
from hercs.net.transport import Transport
from hercs.net.transport_errors import RemoteError
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.run.rundir import RunDir
from hercs.wire.codec import episode_to_msg
from tests.integration.launcher_standins import Launcher

pytestmark = [pytest.mark.integration, pytest.mark.learning, pytest.mark.full,
              pytest.mark.timeout(1500)]

EPOCHS = 6
RUN_S = 1200.0
"""The whole run: the learning test's setup takes ~1 min on 2 idle cores; a wide margin."""


def test_a_3e38_episode_from_an_actor_certificate_is_refused_and_reach_still_learns(
        tmp_path: Path) -> None:
    certs = tmp_path / "certs"
    make_certs(certs, credentials=True)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    run_dir = tmp_path / "runs" / "poisoned"
    launcher = Launcher(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--method", "her",
         "--actors", "2", "--epochs", str(EPOCHS), "--seed", "1", "--run", "poisoned",
         "--run-dir", str(tmp_path / "runs"), "--listen", endpoint, "--tls-dir", str(certs),
         "--credentials", str(certs / "credentials.txt"),
         "--set", "training.cycles_per_epoch=10", "--set", "training.eval_episodes=20"],
        cwd=tmp_path)
    try:
        launcher.wait_for_line(r"^epoch 2/6  success", timeout_s=RUN_S)
        security = SecurityConfig(tls_ca=str(certs / "ca.pem"), tls_cert=str(certs / "actor.pem"),
                                  tls_key=str(certs / "actor.key"),
                                  credentials=str(certs / "credentials.txt"))
        settings = zenoh_settings(security, mode="client", role="actor", endpoints=[endpoint])
        keys = RunKeys("poisoned")
        with Transport.open(mode="client", connect=[endpoint], connect_timeout_s=30,
                            settings=settings) as intruder:
            weights: queue.Queue[bytes] = queue.Queue()
            intruder.subscribe(keys.weights, lambda _, payload: weights.put(payload))
            version = pb.Weights.FromString(weights.get(timeout=60)).version
            spec = load_yaml(RunDir(run_dir).config).task.spec
            episode = random_episode(spec, np.random.default_rng(0), actor_id="actor-9@1",
                                     seq=0)
            episode.obs[:] = np.float32(3e38)
            episode.policy_version = int(version)
            message = episode_to_msg(episode, run="poisoned", task=spec.name)
            with pytest.raises(RemoteError) as refused:
                intruder.request(keys.insert, message.SerializeToString(), timeout_s=60)
        assert refused.value.reason == "implausible", refused.value
        assert launcher.finish(timeout_s=RUN_S) == 0, "\n".join(launcher.out + launcher.err)
    finally:
        launcher.kill()
    with RunDir(run_dir).metrics.open(newline="") as f:
        rows = list(csv.DictReader(f))
    success = [float(r["success_rate"]) for r in rows]
    assert len(success) == EPOCHS
    assert max(success[-3:]) >= 0.9, f"success per epoch: {success}"
    assert "implausible:1" in rows[-1]["rejects"], rows[-1]["rejects"]
    assert any(line.endswith("refused 1 bad episode") for line in launcher.out), launcher.out
