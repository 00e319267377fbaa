"""Child process of the episode-log fault tests: appends episodes 0, 1, 2, … to a new log and
prints each id once `append_episode` returned (when the replay would ack); the parent SIGKILLs it.

    python -m tests.unit.hercs.episode_log_child LOG_PATH TASK [MAX_FILE_BYTES]  # fails a write

`make_episode` is shared with the test so that the parent can check recovered content."""

from __future__ import annotations

import resource
import signal
import sys

import numpy as np

from bench.synthetic_episodes import random_episode
from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.wire.codec import episode_to_msg

RUN = "log-test"
SEED = 20240917


def make_episode(i: int, task: str) -> pb.Episode:
    """Episode i of the tests: the same bytes in every process."""
    rng = np.random.default_rng([SEED, i])
    episode = random_episode(task_spec(task), rng, actor_id=f"actor-{i % 3}", seq=i)
    episode.success = i % 4 == 0
    episode.policy_version = i // 5
    return episode_to_msg(episode, run=RUN, task=task)


def main(path: str, task: str, max_file_bytes: int | None) -> None:
    from hercs.run.runlog import EpisodeLogError, EpisodeLogWriter

    if max_file_bytes is not None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails: EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (max_file_bytes, max_file_bytes))
    writer = EpisodeLogWriter(path, run=RUN, task=task)
    for i in range(1_000_000):
        try:
            writer.append_episode(make_episode(i, task), episode_id=i)
        except (OSError, EpisodeLogError) as exc:  # the scene thread may hit the limit first
            print(f"failed {exc}", flush=True)
            try:
                writer.append_episode(make_episode(i + 1, task), episode_id=i + 1)
            except EpisodeLogError:
                print("refused", flush=True)
            writer.close()  # no footer after a failed append: recovery seals the file
            return
        print(i, flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else None)
