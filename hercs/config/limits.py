"""The numbers the config's bounds (hercs.config.bounds) and their users share: what the wire,
the OS and the arithmetic can hold, the replay's limits on one request, and the reference
machine's speeds that hercs' estimates of time assume."""

from __future__ import annotations

import threading

# -- what the wire, the OS and the arithmetic can hold ------------------------------------------

UINT32_MAX = 2**32 - 1
"""The largest value of a proto `uint32` field (SampleRequest.batch_size, EvalResult.episodes)."""
EXACT_COUNT = 2**53
"""The largest count every place hercs keeps one holds exactly: the counts of a run (epochs,
weights versions, env steps, updates, episodes) travel in `Metrics.values` and land in
metrics.csv as doubles, exact to 2^53; the proto's uint64 and int64 fields hold more. The
audit's `training.epochs=1e300` passed every check and failed in the learner with protobuf's
`ValueError: Value out of range`, six times over."""
PROTOBUF_MAX_BYTES = 2**31 - 1
"""The largest message protobuf encodes or parses: its sizes are signed 32-bit integers."""
ADDRESS_SPACE_BYTES = 2**47
"""128 TiB: the user address space of a 64-bit Linux process on x86-64 (47 bits): no process
can hold more, whatever the machine's memory."""
PID_MAX_LIMIT = 2**22
"""Linux's most tasks (`PID_MAX_LIMIT` on 64-bit): every thread takes one."""
MAX_WAIT_S = min(24 * 3600.0, threading.TIMEOUT_MAX)
"""The longest timeout or wait a config may set: a day (and never past `threading.TIMEOUT_MAX`,
the most `Event.wait` takes; 1e300 made `ValueError: negative timeout` in the actor). A wait
is a guard against something that may never come; one longer than a day guards nothing
`hercs up` still watches: its stall watchdog (`MAX_STALL_S`) has ended a run that stood
still that long."""
MAX_STALL_S = 24 * 3600.0
"""The most the stall watchdog of `hercs up` waits without an epoch's end: a day, 10,000
epochs of the paper's config on the reference machine (8.1 s each, docs/PERFORMANCE.md) or
ten of an epoch of 2.4 hours. Its bound is `launch.stall_factor` times the slowest epoch so
far, or before the first times the first epoch the config predicts, which grows with the
config (the audit's batch of 10^9 rows: 922 days, so the watchdog never fired). A run
whose epochs take longer than a day sets `launch.stall_factor=0`."""
ZENOH_MAX_SESSIONS = 1000
"""Sessions a Zenoh router accepts by default (`transport/unicast/max_sessions`; hercs does not
change it): each actor process is one, and the run's other services take six more."""

# -- the replay's limits on one sample request (hercs.replay_service.replay_messages) ----------

MAX_MINIBATCHES_PER_REQUEST = 400
"""Minibatches the replay serves in one Batch (the learner asks for a cycle's,
`training.minibatches_per_cycle`); a larger request is refused, every time."""
MAX_BATCH_SIZE = 8192
"""Transitions per minibatch the replay serves (32× the paper's 256); a larger request is
refused, every time: the audit's `ddpg.batch_size=10**9` left the learner asking for ever."""
MAX_ROWS_PER_REQUEST = 1 << 18
"""Transitions in one Batch reply: 262,144 rows, ~61 MB for the object tasks (the learner asks
for 40 × 256 = 10,240). Without it one valid request could make the replay build GBs."""

# -- the reference machine: what hercs' estimates of time assume --------------------------------

STARTUP_S = 60.0
"""Starting the services before the first episode: importing torch and MuJoCo, making the
envs and joining the router took 10-25 s per `hercs up` on this project's 2-core development
machine under its usual load; 60 leaves a slower machine room [DESIGN]."""
UPDATE_S = 0.017
"""CPU seconds of one DDPG update at the paper's sizes (minibatch 256, 3 hidden layers of
256) on one core of the development machine (docs/PERFORMANCE.md: 16.8 ms); it scales with
the minibatch and the layers' size. A GPU learner is faster: this only makes the bound
longer there."""
ENV_STEP_S = 0.001
"""Seconds of one env step with its policy call: the development machine's raw FetchPush-v4
steps at 1,339/s (docs/PERFORMANCE.md §3); heavier simulators (the hand tasks) run a few
times slower, which the stall factor covers, and a bound that assumes this speed refuses
only what no machine does."""
ACTOR_PROCESS_BYTES = 256 * 2**20
"""Memory one actor process holds at least: torch, MuJoCo and its envs took 340 MB resident
for one FetchPush env on the development machine; 256 MiB refuses only what cannot run."""

# -- hercs' own limits --------------------------------------------------------------------------

MAX_BACKOFF_S = 30.0
"""Restart delays of `hercs up` double from `launch.restart_backoff_s` up to this."""
INSERT_WORKERS_PER_CPU = 8
"""The replay's insert workers overlap fsyncs, not computation (they share the GIL): 8 per
CPU leaves a slow disk room, and past it workers only take memory and slow the stop (the
audit's 10^6 took 2.5 GB and kept the replay from obeying SIGTERM within 10 s)."""
MAX_ENVS_PER_PROCESS = 256
"""Envs one actor process steps side by side, 16× the most measured: the batched policy
call's gain is flat from 2 envs up (docs/PERFORMANCE.md §8), and each more env is one more
simulator that one core steps in turn."""
