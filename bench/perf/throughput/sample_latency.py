"""4. Sample latency of a SampleRequest over Zenoh on a full buffer, per sampler, against
`ReplayTable.draw` of the same size in this process."""

from __future__ import annotations

import time

from bench.perf.throughput import BenchError, say
from bench.perf.throughput.harness import Child, Harness
from bench.perf.throughput.plan import MAX_REPLY_BYTES, REQUEST_TIMEOUT_S, RUN, SEED
from bench.perf.throughput.rates import percentile
from bench.perf.throughput.synthetic import cluster_centroids, fill_table
from bench.perf.throughput.throughput_report import Figure, Target
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.builder import ReplayBuilder
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.seeding import generator
from hercs.wire.codec import cluster_model_to_msg
from hercs.wire.validation import parse_message


def sample_over_zenoh(bench: Harness, method: str) -> list[float]:
    """Per-request seconds, request sent → reply bytes received, after a warm-up."""
    p = bench.plan
    out: list[float] = []
    for i in range(p.sample_warmup_requests + p.sample_requests):
        request = pb.SampleRequest(
            schema_version=SCHEMA_VERSION, run=RUN, learner_id="bench", request_id=i + 1,
            num_minibatches=p.sample_minibatches, batch_size=p.sample_batch_size)
        payload = request.SerializeToString()
        start = time.perf_counter()
        raw = bench.client.request(bench.keys.sample, payload, timeout_s=REQUEST_TIMEOUT_S)
        elapsed = time.perf_counter() - start
        batch = parse_message(raw, pb.Batch, max_bytes=MAX_REPLY_BYTES)
        if len(batch.minibatches) != p.sample_minibatches:
            raise BenchError(f"{method}: a Batch of {len(batch.minibatches)} minibatches, "
                             f"asked for {p.sample_minibatches}")
        # Episodes without a cluster label are not counted in cluster_draws, so a Batch
        # drawn before the replay adopted a model counts none.
        if bench.configs[method][0].run.uses_clusters and sum(batch.cluster_draws) == 0:
            raise BenchError(f"{method}: the replay sampled without a cluster model "
                             f"(Batch.cluster_draws {list(batch.cluster_draws)})")
        if i >= p.sample_warmup_requests:
            out.append(elapsed)
    return out


def sample_in_process(bench: Harness, method: str, episodes: int) -> list[float]:
    """Per-request seconds of `ReplayTable.draw` here, on a store of the same size."""
    p = bench.plan
    config = bench.configs[method][0]
    table = ReplayBuilder(config).table(rng=generator(SEED, "bench", "sample-core"))
    fill_table(table, bench.pool, episodes)
    if config.run.uses_clusters:
        table.adopt_cluster_model(ClusterModel(version=1, centroids=cluster_centroids(
            bench.spec), n_goals=config.cluster.fgb_size, failures_seen=episodes), None)
    out = []
    for i in range(p.sample_warmup_requests + p.sample_requests):
        start = time.perf_counter()
        table.draw(p.sample_minibatches, p.sample_batch_size)
        if i >= p.sample_warmup_requests:
            out.append(time.perf_counter() - start)
    return out


def measure(bench: Harness, method: str, episodes: int) -> None:
    p = bench.plan
    ours_s = sample_over_zenoh(bench, method)
    ref_s = sample_in_process(bench, method, episodes)
    stats = {}
    for per, divide in (("minibatch", p.sample_minibatches), ("request", 1)):
        for q in (50, 99):
            ours = percentile(ours_s, q) * 1e3 / divide
            reference = percentile(ref_s, q) * 1e3 / divide
            stats[f"p{q}_{per}_ms"] = {"ours": ours, "reference": reference}
            size = f"{p.sample_minibatches}×{p.sample_batch_size}"
            bench.figures.append(Figure(
                key=f"sample_p{q}_{per}_{method}",
                name=f"sample p{q} per {per}, {method}", unit="ms", ours=ours,
                reference=reference,
                ours_what=f"SampleRequest of {size} over Zenoh to the replay holding "
                          f"{episodes * bench.spec.episode_steps:,} transitions, request "
                          f"→ reply bytes at a client"
                          + (", ÷ 40" if per == "minibatch" else ""),
                reference_what=f"`ReplayTable.draw` of {size} in one process on a store "
                               "of the same size" + (", ÷ 40" if per == "minibatch"
                                                     else ""),
                target=Target("ours_at_most", 1.0) if (q, per) == (99, "minibatch")
                else None))
    bench.details.setdefault("samples", {})[method] = {
        "requests": len(ours_s), "stored_episodes": episodes, **stats}
    say(f"sample {method}: p50 {stats['p50_minibatch_ms']['ours']:.2f} ms, p99 "
        f"{stats['p99_minibatch_ms']['ours']:.2f} ms per minibatch over Zenoh "
        f"(in process p99 {stats['p99_minibatch_ms']['reference']:.2f} ms)")


def publish_cluster_model(bench: Harness, replay: Child) -> None:
    centroids = cluster_centroids(bench.spec)
    publisher = bench.client.publisher(bench.keys.cluster_model, latest=True, block=True)
    fgb_size = bench.configs["her-cs"][0].cluster.fgb_size
    model = ClusterModel(version=1, centroids=centroids, n_goals=fgb_size,
                         failures_seen=fgb_size)
    publisher.put(cluster_model_to_msg(model).SerializeToString())
    status = bench.wait_status(lambda s: s.cluster_model_version >= 1,
                              what="cluster model v1 adopted", replay=replay)
    bench.details.setdefault("samples", {})["her-cs_cluster_sizes"] = list(
        status.cluster_sizes)
