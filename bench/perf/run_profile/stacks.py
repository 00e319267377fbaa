"""py-spy's raw output of a whole run, parsed and sorted into the function groups of the profile.

A raw line is `frame;frame;…;frame COUNT`, outermost first; the innermost `process PID:...`
frame names the process. Samples of threads parked in native waits are idle and dropped; each
process's CPU time comes from /proc (docs/PERFORMANCE.md §3, "Where the time goes").
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

PROCESS_FRAME = re.compile(r'^process (\d+):"(.*)"$')
SERVICE_COMMAND = re.compile(r"hercs\.apps\.cli (\w+)(?:.*--id (\S+))?")

WAIT_LEAF = re.compile(
    r"park|futex|condvar|pthread_cond_\w*wait|select_select|epoll_wait|poll\b|nanosleep"
    r"|sem_\w*wait|recv|accept|do_futex|wait_optional_timeout|_PyThread_wait|lock_PyThread"
    r"|acquire_timed|PyThread_acquire_lock|sleep \(|^syscall \(libc|^0x[0-9a-f]+ \(libc\.so",
    re.IGNORECASE)
"""A leaf frame of a thread that waits (its sample is idle time, not work). libc's frames
without a symbol are its internal syscall wrappers (futex and poll waits, in practice)."""

GROUPS = ("GEMMs", "rest of the update", "Adam", "sampling and relabelling",
          "serialisation and Zenoh", "env stepping", "policy inference (actor)",
          "evaluation", "clustering", "start-up (imports)", "launcher and router", "other")
"""The profile's function groups, in the order the report gives them (plus idle)."""

_RULES: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("start-up (imports)", re.compile(r"<frozen importlib|_find_and_load")),
    ("Adam", re.compile(r"_fused_adam|torch/optim/adam\.py|optimizer\.py.*\bstep\b"
                        r"|zero_grad")),
    # oneDNN's and MKL's GEMM kernels are JIT code without symbols: a native stack that ends
    # under a Linear's forward or under the autograd engine's backward call is inside one
    ("GEMMs", re.compile(r"forward \(torch/nn/modules/linear\.py:\d+\)$"
                         r"|_engine_run_backward \(torch/autograd/graph\.py:\d+\)$"
                         r"|gemm|dnnl|mkl_|brgemm|addmm|at::native::\w*mm\b")),
    ("rest of the update", re.compile(r"hercs/learner/ddpg\.py")),
    ("sampling and relabelling", re.compile(r"replay_service/(samplers/|her\.py|sampling_index"
                                            r"|energy\.py)|sample \(hercs/replay_service")),
    ("env stepping", re.compile(r"mujoco|gymnasium|hercs/rl/goal_env\.py|hercs/rl/envs\.py")),
    ("policy inference (actor)", re.compile(r"hercs/rl/policy\.py|hercs/rl/networks\.py")),
    ("serialisation and Zenoh", re.compile(r"zenoh|protobuf|_pb2|hercs/wire/|hercs/net/"
                                           r"|SerializeToString|ParseFromString|mcap")),
)


@dataclass
class ProcessSamples:
    """One process's samples: its role (`learner`, `actor-0`, …), idle samples dropped, and
    the busy samples' stacks."""

    pid: int
    role: str
    stacks: Counter[str] = field(default_factory=Counter)
    idle: int = 0

    @property
    def busy(self) -> int:
        return sum(self.stacks.values())


def role_of(command: str) -> str:
    """`actor-0`, `evaluator-0`, `learner`, `replay`, `clusterer` or `up` from a service's
    command line; `other` for a process that is none of them."""
    found = SERVICE_COMMAND.search(command)
    if found is None:
        return "other"
    command_name, ident = found.groups()
    if command_name in {"actor", "evaluator"} and ident:
        return ident
    return command_name


def parse_raw(lines: Iterable[str]) -> dict[int, ProcessSamples]:
    """pid → its samples, from py-spy's raw (collapsed-stack) output."""
    processes: dict[int, ProcessSamples] = {}
    for line in lines:
        line = line.rstrip("\n")
        stack, _, count_text = line.rpartition(" ")
        if not stack or not count_text.isdigit():
            continue
        frames = stack.split(";")
        depth = 0  # the process frames lead; the innermost one is the sampled process
        while depth < len(frames) and PROCESS_FRAME.match(frames[depth]):
            depth += 1
        if depth == 0:
            continue
        match = PROCESS_FRAME.match(frames[depth - 1])
        assert match is not None
        pid = int(match.group(1))
        process = processes.setdefault(pid, ProcessSamples(pid, role_of(match.group(2))))
        body = frames[depth:]
        if not body or WAIT_LEAF.search(body[-1]):
            process.idle += int(count_text)
        else:
            process.stacks[";".join(body)] += int(count_text)
    return processes


def group_of(role: str, stack: str) -> str:
    """The function group of one busy stack of a process in `role`."""
    if role.startswith("evaluator"):
        return "start-up (imports)" if _RULES[0][1].search(stack) else "evaluation"
    if role == "clusterer":
        return "start-up (imports)" if _RULES[0][1].search(stack) else "clustering"
    if role == "up":
        return "launcher and router"
    for group, pattern in _RULES:  # the whole stack; the GEMM rule anchors at its leaf
        if group in {"rest of the update", "Adam", "GEMMs"} and role != "learner":
            continue
        if pattern.search(stack):
            return group
    return "other"


def group_shares(process: ProcessSamples) -> dict[str, float]:
    """Each group's share of the process's busy samples (summing to 1; empty if none)."""
    counts: Counter[str] = Counter()
    for stack, count in process.stacks.items():
        counts[group_of(process.role, stack)] += count
    total = sum(counts.values())
    return {group: count / total for group, count in counts.items()} if total else {}


_KERNEL = re.compile(r"\w+_kernel\w*")
_TEMPLATE = re.compile(r"<[^<>]*>")


def short_frame(frame: str, width: int = 80) -> str:
    """A frame's name for the report: a C++ template instance named by the kernel inside it
    (`clamp_min_scalar_kernel_impl (libtorch_cpu.so)`), template arguments dropped."""
    name, _, where = frame.rpartition(" (")
    if "<" in name:
        kernel = _KERNEL.findall(name)
        if kernel:
            name = kernel[-1]
        else:
            while _TEMPLATE.search(name):
                name = _TEMPLATE.sub("", name)
    text = f"{name} ({where}" if where else frame
    return text if len(text) <= width else text[:width - 1] + "…"


def top_frames(process: ProcessSamples, n: int = 12) -> list[tuple[str, float]]:
    """The process's `n` heaviest innermost frames with their share of its busy samples: the
    summary of its flame graph that the report commits (the raw stacks are not)."""
    leaves: Counter[str] = Counter()
    for stack, count in process.stacks.items():
        leaves[short_frame(stack.rsplit(";", 1)[-1])] += count
    total = process.busy or 1
    return [(frame, count / total) for frame, count in leaves.most_common(n)]
