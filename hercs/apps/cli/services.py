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
from hercs.roles import SERVICE_ROLES

Command = Callable[[argparse.Namespace, HercsConfig], int]

HARD_EXIT_SERVICES = frozenset(r.module for r in SERVICE_ROLES.values() if r.hard_exit)
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
