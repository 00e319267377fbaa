"""What a config makes, in bytes (its messages, its store, its networks), and what the machine a
run starts on can hold; the sizes hercs.config.bounds holds against the limits."""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hercs.rl.task_spec import TaskSpec


@dataclass(frozen=True)
class Machine:
    """What the machine a run starts on can hold."""

    memory_bytes: int
    """Physical memory, or the cgroup's limit where a container has a smaller one."""
    cpus: int
    """CPUs this process may run on (affinity, and a cgroup's CPU quota)."""


@functools.cache
def this_machine() -> Machine:
    """The machine this process runs on (read once)."""
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for limit in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        text = _read(limit)
        if text.isdigit():
            memory = min(memory, int(text))
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)
    quota, _, period = _read("/sys/fs/cgroup/cpu.max").partition(" ")
    if quota.isdigit() and period.isdigit() and int(period) > 0:
        cpus = min(cpus, max(1, math.ceil(int(quota) / int(period))))
    return Machine(memory_bytes=memory, cpus=cpus)


def _read(path: str) -> str:
    try:
        return Path(path).read_text().strip()
    except OSError:
        return ""


FLOAT32_BYTES = 4
MESSAGE_OVERHEAD_BYTES = 4096
"""What a message holds besides its arrays' data (names, dtypes, shapes, ids, run and actor
names, counters): well under 4 KiB for every message the bounds measure."""


def episode_message_bytes(spec: TaskSpec, steps: int | None = None) -> int:
    """An `Episode` on the wire: obs and ag of T+1 steps, g and actions of T, in float32
    (T: `steps`, or the task's)."""
    t = spec.episode_steps if steps is None else steps
    floats = (t + 1) * (spec.obs_dim + spec.goal_dim) + t * (spec.goal_dim + spec.action_dim)
    return FLOAT32_BYTES * floats + MESSAGE_OVERHEAD_BYTES


def stored_episode_bytes(spec: TaskSpec, clusters: int) -> int:
    """One slot of the replay's store (hercs.replay_service.store.EpisodeStore) with its
    sampling index: the episode's arrays, its metadata (ids, seq, success, final achieved
    goal, energy, cluster, version, moved, the actor id's string) and the index's position,
    label, energy and, with `clusters` clusters, one int64 per cluster's member list."""
    arrays = episode_message_bytes(spec) - MESSAGE_OVERHEAD_BYTES
    metadata = 8 + 8 + 64 + 8 + 1 + FLOAT32_BYTES * spec.goal_dim + 8 + 4 + 8 + 1
    index = 8 + 8 + 8 + 8 * clusters
    return arrays + metadata + index


def mlp_parameters(in_dim: int, out_dim: int, hidden_size: int, hidden_layers: int) -> int:
    """Weights and biases of hercs.rl.networks' MLP: in → hidden × layers → out."""
    first = (in_dim + 1) * hidden_size
    middle = (hidden_layers - 1) * (hidden_size + 1) * hidden_size
    return first + middle + (hidden_size + 1) * out_dim


def actor_parameters(spec: TaskSpec, hidden_size: int, hidden_layers: int) -> int:
    return mlp_parameters(spec.obs_dim + spec.goal_dim, spec.action_dim, hidden_size,
                          hidden_layers)


def critic_parameters(spec: TaskSpec, hidden_size: int, hidden_layers: int) -> int:
    return mlp_parameters(spec.obs_dim + spec.goal_dim + spec.action_dim, 1, hidden_size,
                          hidden_layers)


def weights_message_bytes(spec: TaskSpec, hidden_size: int, hidden_layers: int) -> int:
    """A `Weights` broadcast: the actor's parameters in float32 and two normalisers' four
    float64 statistics (sum, sumsq, mean, std)."""
    stats = 4 * 8 * (spec.obs_dim + spec.goal_dim)
    return (FLOAT32_BYTES * actor_parameters(spec, hidden_size, hidden_layers) + stats
            + MESSAGE_OVERHEAD_BYTES)


def learner_parameter_bytes(spec: TaskSpec, hidden_size: int, hidden_layers: int) -> int:
    """The learner's parameter memory: the actor and the critic, each with its target, its
    gradients and Adam's two moments, five float32 copies."""
    params = (actor_parameters(spec, hidden_size, hidden_layers)
              + critic_parameters(spec, hidden_size, hidden_layers))
    return 5 * FLOAT32_BYTES * params


def batch_message_bytes(spec: TaskSpec, batch_size: int, minibatches: int) -> int:
    """A `Batch` reply: each minibatch's o, o2, g, u and r in float32, plus the normalisers'
    statistics."""
    row = spec.obs_dim * 2 + spec.goal_dim + spec.action_dim + 1
    stats = 4 * 8 * (spec.obs_dim + spec.goal_dim)
    return FLOAT32_BYTES * row * batch_size * minibatches + stats + MESSAGE_OVERHEAD_BYTES


def approx(n: float) -> str:
    """`n` to three digits, however large an integer it is."""
    try:
        return f"{float(n):.3g}"
    except OverflowError:
        return f"1e+{len(str(int(n))) - 1}"


def size_text(n: float) -> str:
    """Bytes as people read them: 512 B, 8.0 MiB, 36 PiB."""
    if n >= 2**70:
        return f"{approx(n / 2**60)} EiB"
    for unit, scale in (("EiB", 2**60), ("PiB", 2**50), ("TiB", 2**40), ("GiB", 2**30),
                        ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            value = n / scale
            return f"{value:.0f} {unit}" if value >= 100 else f"{value:.1f} {unit}"
    return f"{n:.0f} B"


def largest(fits: Callable[[int], bool], *, start: int = 1) -> int:
    """The largest n >= start - 1 with fits(n), for fits true up to some n and false after
    (start - 1 when even `start` does not fit)."""
    if not fits(start):
        return start - 1
    low, high = start, start * 2
    while fits(high):
        low, high = high, high * 2
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (middle, high) if fits(middle) else (low, middle)
    return low
