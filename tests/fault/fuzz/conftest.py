"""The world every fuzz module shares, started once for the package (see __init__)."""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest

from hercs.apps.launch.router import free_port
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.net.transport import Transport
from hercs.proto import hercs_pb2 as pb
from tests.fault.fuzz.oracles import ModelOracle
from tests.fault.fuzz.probes import BASE_EPISODES, FIRST_MODEL_VERSION, make_model, make_weights
from tests.fault.fuzz.runs import (
    KA,
    KL,
    KR,
    REQUEST_TIMEOUT_S,
    RUN_A,
    WAIT_S,
    actor_config,
    learner_config,
    replay_config,
)
from tests.fault.fuzz.standins import ActorRunReplay, LearnerRunReplay
from tests.fault.fuzz.world import Ledger, World
from tests.integration.services import ServiceProcess


def _subscribe_queue(transport: Transport, key: str, parse: Callable[[bytes], Any], **kw: Any
                     ) -> queue.Queue:
    out: queue.Queue = queue.Queue()
    transport.subscribe(key, lambda _key, raw: out.put(parse(raw)), **kw)
    return out


def _metrics_values(raw: bytes) -> dict[str, float]:
    return dict(pb.Metrics.FromString(raw).values)


@pytest.fixture(scope="package")
def world(tmp_path_factory: pytest.TempPathFactory) -> Iterator[World]:
    tmp = tmp_path_factory.mktemp("fuzz")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run_dir = tmp / "runs"
    configs = {"replay": replay_config(endpoint, run_dir),
               "actor": actor_config(endpoint, run_dir),
               "learner": learner_config(endpoint, run_dir)}
    paths = {}
    for name, config in configs.items():
        paths[name] = tmp / f"{name}.yaml"
        save_yaml(config, paths[name])
    actor_local = apply_overrides(HercsConfig(), [f"run.name={RUN_A}",
                                                  f"transport.connect=[{endpoint}]"])
    save_yaml(actor_local, tmp / "actor-local.yaml")

    router = Transport.open(mode="router", listen=[endpoint])
    client = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=10)
    standin = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=10)
    procs: dict[str, ServiceProcess] = {}
    actor_replay = learner_replay = None
    pool = ThreadPoolExecutor(max_workers=6, thread_name_prefix="fz-ask")
    try:
        alive: queue.Queue[tuple[str, bool]] = queue.Queue()
        client.watch_alive("hercs/*/alive/**", lambda key, up: alive.put((key, up)))
        status = _subscribe_queue(client, KR.status, pb.ReplayStatus.FromString)
        metrics = {role: _subscribe_queue(client, keys.metrics(role), _metrics_values)
                   for role, keys in (("clusterer", KR), ("actor", KA), ("evaluator", KA),
                                      ("learner", KL))}
        eval_results = _subscribe_queue(client, KA.eval_result, pb.EvalResult.FromString)
        learner_weights = _subscribe_queue(client, KL.weights, pb.Weights.FromString,
                                           latest=True, capacity=4096)
        actor_replay = ActorRunReplay(standin, configs["actor"])
        learner_replay = LearnerRunReplay(standin)

        procs["replay"] = ServiceProcess("replay", paths["replay"], "r0", tmp)
        procs["clusterer"] = ServiceProcess("clusterer", paths["replay"], "c0", tmp)
        procs["actor"] = ServiceProcess("actor", tmp / "actor-local.yaml", "a0", tmp)
        procs["evaluator"] = ServiceProcess("evaluator", paths["actor"], "e0", tmp)
        procs["learner"] = ServiceProcess("learner", paths["learner"], "l0", tmp)
        expected_alive = {KR.alive("replay", "r0"), KR.alive("clusterer", "c0"),
                          KA.alive("actor", "a0"), KA.alive("evaluator", "e0"),
                          KL.alive("learner", "l0")}
        deadline = time.monotonic() + 90
        up: set[str] = set()
        while not expected_alive <= up:
            try:
                key, is_up = alive.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                raise AssertionError(f"services not up: {expected_alive - up}") from None
            if is_up:
                up.add(key)

        w = World(tmp=tmp, client=client, procs=procs, configs=configs,
                  actor_replay=actor_replay, learner_replay=learner_replay, pool=pool,
                  ledger=Ledger(), model_oracle=ModelOracle(),
                  weights_pub=client.publisher(KA.weights, latest=True, block=True),
                  model_pub=client.publisher(KR.cluster_model, latest=True, block=True),
                  puts={key: client.publisher(key, block=True)
                        for key in (KR.eval_result, KR.inserted, KA.eval_request, KA.progress,
                                    KL.eval_result)},
                  status=status, metrics=metrics, eval_results=eval_results,
                  learner_weights=learner_weights)
        # The clusterer has asked the replay for its state (a fresh run) before any insert,
        # so every header counts; the evaluator has subscribed; the actor rolls out.
        w.metrics_of("clusterer", lambda m: True, "anything")
        w.metrics_of("evaluator", lambda m: True, "anything")
        actor_replay.next_versions(lambda v: v == -1, "with the initial policy")
        for msg in BASE_EPISODES:
            ack = pb.InsertAck.FromString(client.request(
                KR.insert, msg.SerializeToString(), timeout_s=REQUEST_TIMEOUT_S))
            assert not ack.duplicate
            w.ledger.stored[ack.episode_id] = msg
            w.ledger.keys[(msg.actor_id, msg.seq)] = ack.episode_id
        assert sorted(w.ledger.stored) == list(range(len(BASE_EPISODES)))
        for key in w.puts:
            assert w.puts[key].wait_for_subscribers(WAIT_S), f"nobody subscribes to {key}"
        w.model_pub.put(make_model(FIRST_MODEL_VERSION, 0).SerializeToString())
        assert w.model_oracle(make_model(FIRST_MODEL_VERSION, 0).SerializeToString()) == "adopted"
        w.ledger.models.append(FIRST_MODEL_VERSION)
        w.replay_status(lambda s: s.cluster_model_version == FIRST_MODEL_VERSION,
                        "the first cluster model")
        first = make_weights(version=1, epoch=1, evaluate=True, seed=5)
        w.weights_pub.put(first.SerializeToString())
        w.ledger.actor_versions.add(1)
        w.ledger.eval_keys.add((1, 1))
        actor_replay.next_versions(lambda v: v == 1, "with weights version 1")
        result = eval_results.get(timeout=WAIT_S)
        assert (result.epoch, result.weights_version) == (1, 1)
        w.ledger.evaluated.add((1, 1))
        w.assert_running()
        yield w
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs.values():
            if proc.proc.poll() is None:
                proc.kill()
        for standin_part in (actor_replay, learner_replay):
            if standin_part is not None:
                standin_part.close()
        client.close()
        standin.close()
        router.close()
