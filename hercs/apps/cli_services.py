"""The service commands of the `hercs` CLI (`hercs replay`, `hercs actor`, …): which module runs
each role, and how a service process ends once its orderly close is done. Each module has
`run(config, *, ident) -> int` and is imported only when used, so `hercs --help` stays fast.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable
from typing import NoReturn

from hercs.config import HercsConfig

Command = Callable[[argparse.Namespace, HercsConfig], int]

# Service commands: each module has `run(config, *, ident) -> int` (exit status). Imported only
# when used, so `hercs --help` stays fast.
SERVICE_EXAMPLES = {
    "replay": "hercs replay --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "clusterer": "hercs clusterer --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "learner": "hercs learner --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "evaluator": "hercs evaluator --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "actor": "hercs actor --connect tcp/LEARNER_HOST:7447 --run myrun",
    "live": "hercs live --connect tcp/LEARNER_HOST:7447 --run myrun --rerun",
}

SERVICES: dict[str, tuple[str, str]] = {
    "replay": ("hercs.replay_service.replay_shell",
               "run the replay service (episode store, HER, samplers)"),
    "clusterer": ("hercs.clusterer.clusterer_shell",
                  "run the clusterer (failed goals, k-means refits)"),
    "learner": ("hercs.learner.learner_shell", "run the DDPG learner (updates, weights, epochs)"),
    "actor": ("hercs.actors.actor_shell",
              "run a rollout actor (join a run with --connect and --run)"),
    "evaluator": ("hercs.actors.evaluator", "run the evaluator (deterministic test episodes)"),
    "live": ("hercs.apps.live_view", "stream a run to Rerun while it trains (what `hercs up "
                                "--rerun` starts; join a run with --connect and --run)"),
}


HARD_EXIT_SERVICES = frozenset(module for role, (module, _) in SERVICES.items()
                               if role != "live")
"""Services whose process ends with `exit_after_close` (not the live view: the Rerun SDK
flushes its recording in an exit handler)."""


def exit_after_close(code: int) -> NoReturn:
    """End a service process as soon as its orderly close is done, without interpreter
    teardown.

    When a service's `run` returns it has closed its Zenoh session, joined its threads (up
    to `hercs.net.service_shell.THREAD_JOIN_S`) and made everything it acknowledged durable;
    teardown adds nothing but the finalisation of native threads, and there a clusterer stopped with
    SIGTERM once aborted (SIGABRT, glibc's "FATAL: exception not rethrown": a native thread
    unwound by the exiting interpreter; seen once in `make test` on a loaded machine, after
    a clean stop). So: wait for non-daemon threads as a normal exit would, flush the logs
    and the standard streams, and `os._exit`."""
    import logging
    import os
    import threading

    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def service_command(module: str) -> Command:
    """The CLI command that runs service `module` in this process."""
    def command(args: argparse.Namespace, config: HercsConfig) -> int:
        from importlib import import_module

        code = int(import_module(module).run(config, ident=args.ident))
        if module in HARD_EXIT_SERVICES:
            exit_after_close(code)
        return code

    return command
