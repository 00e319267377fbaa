"""One compute thread per service process.

A run is many single-threaded processes sharing the host's cores, and a library that spreads
one process's arithmetic over every core competes with the others: OpenBLAS does so by itself
for matrix products of 8 rows or more, and on a busy 2-core machine the actor's batched policy
call (8 envs) took 3.4 ms instead of 0.15 (bench/perf/actor_envs.py). So every service
(`hercs.net.service_shell.service_main`) limits the BLAS and OpenMP thread pools, and torch's
intra-op threads where torch is loaded, to one.
"""

from __future__ import annotations

import sys

from threadpoolctl import threadpool_limits


def single_threaded_numerics() -> None:
    """Limit numpy's BLAS, OpenMP pools and (if this process imported it) torch to one
    thread."""
    threadpool_limits(limits=1)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)
