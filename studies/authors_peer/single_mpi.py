"""A one-process stand-in for the part of `mpi4py` the authors' code calls.

Their code averages gradients and normaliser statistics over `MPI.COMM_WORLD`; they ran it with
one worker, where every one of those calls leaves the data as it is: a broadcast from rank 0 to
rank 0, an all-reduce that sums one term, a size of 1. This module gives exactly that, so their
code runs unchanged without an MPI library.
"""

from __future__ import annotations

import types
from typing import Any

import numpy as np

SUM = "sum"
"""The only reduction their code asks for (`op=MPI.SUM`)."""


class SingleWorld:
    """`MPI.COMM_WORLD` of a job with one rank."""

    def Get_rank(self) -> int:  # noqa: N802 - mpi4py's spelling, which their code calls
        return 0

    def Get_size(self) -> int:  # noqa: N802
        return 1

    def Bcast(self, buf: np.ndarray, root: int = 0) -> None:  # noqa: N802
        if root != 0:
            raise ValueError(f"Bcast root: got {root}, the only rank is 0")

    def Allreduce(self, sendbuf: np.ndarray, recvbuf: np.ndarray,  # noqa: N802
                  op: str = SUM) -> None:
        if op != SUM:
            raise ValueError(f"Allreduce op: got {op!r}, only MPI.SUM is provided")
        recvbuf[...] = sendbuf

    def allreduce(self, value: Any, op: str = SUM) -> Any:
        if op != SUM:
            raise ValueError(f"allreduce op: got {op!r}, only MPI.SUM is provided")
        return value


def mpi4py_module() -> types.ModuleType:
    """A module that stands for `mpi4py`, with `mpi4py.MPI` as its `MPI` attribute."""
    mpi = types.ModuleType("mpi4py.MPI", "one-rank stand-in (studies.authors_peer)")
    mpi.COMM_WORLD = SingleWorld()  # type: ignore[attr-defined]
    mpi.SUM = SUM  # type: ignore[attr-defined]
    package = types.ModuleType("mpi4py", "one-rank stand-in (studies.authors_peer)")
    package.MPI = mpi  # type: ignore[attr-defined]
    package.__path__ = []  # a package, so that `from mpi4py import MPI` resolves
    return package
