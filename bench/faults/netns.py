"""Hosts on one machine: network namespaces behind veth links, and the faults of a real network
between hosts (loss, cuts, a narrow link), made with iproute2's `ip` and `tc` and `iptables`.

`problem()` says why none of this can run; `hosts(n)` makes n namespaces and always removes them,
their links and chains. Latency comes from bench.faults.delay_relay (no netem here). How the
faults are made: docs/FAULTS.md, "Network faults"."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass

from bench.common import all_started

TOOLS = ("ip", "tc", "iptables")
SUBNET = "10.125"
"""Host i's link is SUBNET.i.0/24 (i from 1): the host end .1, the namespace end .2.
tests/integration (10.123.0.0/24) and the Slurm test cluster (10.124.0.0/24) use others."""


def _run(*argv: str) -> str:
    done = subprocess.run(list(argv), capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: exit {done.returncode}: "
                           f"{(done.stderr or done.stdout).strip()}")
    return done.stdout


def _quiet(*argv: str) -> None:
    """A clean-up step that may find its object already gone."""
    subprocess.run(list(argv), capture_output=True)


def problem(subnet: str = SUBNET, *, faults: bool = True) -> str | None:
    """Why namespaced hosts (with `faults`, and the faults) cannot be made here, or None.
    For the faults it probes the kernel with a throwaway namespace: a `statistic` match rule
    and a `tbf` qdisc on its loopback."""
    if os.geteuid() != 0:
        return f"network namespaces and iptables need root; this is uid {os.geteuid()}"
    missing = [t for t in (TOOLS if faults else ("ip",)) if shutil.which(t) is None]
    if missing:
        return (f"{', '.join(missing)} not installed (Debian: iproute2 gives ip and tc, "
                "iptables gives iptables; `make netfault-tools` installs them)")
    if subprocess.run(["ip", "-o", "addr", "show", "to", f"{subnet}.0.0/16"],
                      capture_output=True, text=True).stdout.strip():
        return f"{subnet}.0.0/16 is already in use on this host; not touching it"
    if not faults:
        return None
    probe = f"hnf-probe-{os.getpid()}"
    try:
        _run("ip", "netns", "add", probe)
        _run("ip", "netns", "exec", probe, "iptables", "-w", "-A", "INPUT", "-m", "statistic",
             "--mode", "random", "--probability", "0.5", "-j", "DROP")
        _run("ip", "netns", "exec", probe, "tc", "qdisc", "add", "dev", "lo", "root", "tbf",
             "rate", "10mbit", "burst", "32kbit", "latency", "100ms")
    except RuntimeError as exc:
        return f"this kernel or its tools cannot make the faults: {exc}"
    finally:
        _quiet("ip", "netns", "del", probe)
    return None


@dataclass
class Host:
    """A namespace behind a veth link; its faults are set and cleared with the methods."""

    name: str
    """The namespace's name (`ip netns exec NAME`)."""
    host_if: str
    ns_if: str
    host_ip: str
    """The root namespace's end of the link: where a router listens for this host."""
    ns_ip: str
    chain: str
    """The iptables chain (in both namespaces) this host's drops go in, made by the first
    drop (a host without faults needs no iptables)."""
    _chains: bool = False

    def exec_argv(self, argv: list[str]) -> list[str]:
        """`argv` run inside the namespace (same file system, environment and user)."""
        return ["ip", "netns", "exec", self.name, *argv]

    def _iptables(self, side: str, *args: str) -> None:
        prefix = ["ip", "netns", "exec", self.name] if side == "ns" else []
        _run(*prefix, "iptables", "-w", *args)

    def create(self) -> None:
        _run("ip", "netns", "add", self.name)
        _run("ip", "link", "add", self.host_if, "type", "veth", "peer", "name", self.ns_if)
        _run("ip", "link", "set", self.ns_if, "netns", self.name)
        _run("ip", "addr", "add", f"{self.host_ip}/24", "dev", self.host_if)
        _run("ip", "link", "set", self.host_if, "up")
        _run("ip", "-n", self.name, "addr", "add", f"{self.ns_ip}/24", "dev", self.ns_if)
        _run("ip", "-n", self.name, "link", "set", self.ns_if, "up")
        _run("ip", "-n", self.name, "link", "set", "lo", "up")

    def _drop_chains(self) -> None:
        if not self._chains:
            for side, iface in (("root", self.host_if), ("ns", self.ns_if)):
                self._iptables(side, "-N", self.chain)
                self._chains = True  # from here on `remove` has a chain to delete
                self._iptables(side, "-I", "INPUT", "-i", iface, "-j", self.chain)

    def remove(self) -> None:
        """Undo `create` as far as it got (each step may find its object gone)."""
        if self._chains:
            _quiet("iptables", "-w", "-D", "INPUT", "-i", self.host_if, "-j", self.chain)
            _quiet("iptables", "-w", "-F", self.chain)
            _quiet("iptables", "-w", "-X", self.chain)
        _quiet("ip", "netns", "del", self.name)  # takes its veth end, and so the pair
        _quiet("ip", "link", "del", self.host_if)

    # ---------------------------------------------------------------------- faults

    def lose(self, probability: float) -> None:
        """Drop each packet with `probability`, independently, in both directions."""
        if not 0.0 < probability < 1.0:
            raise ValueError(f"loss probability: got {probability}, must be in (0, 1)")
        self._drop_chains()
        for side in ("root", "ns"):
            self._iptables(side, "-A", self.chain, "-m", "statistic", "--mode", "random",
                           "--probability", f"{probability:.6f}", "-j", "DROP")

    def cut(self, *, both_ways: bool = True) -> None:
        """Drop every packet towards the namespace and, with `both_ways`, from it too."""
        self._drop_chains()
        for side in ("root", "ns") if both_ways else ("ns",):
            self._iptables(side, "-I", self.chain, "-j", "DROP")

    def heal(self, *, both_ways: bool = True) -> None:
        """Undo `cut` (the same `both_ways`); other faults stay."""
        for side in ("root", "ns") if both_ways else ("ns",):
            self._iptables(side, "-D", self.chain, "-j", "DROP")

    def limit_rate(self, rate_mbit: float) -> None:
        """A token bucket of `rate_mbit` on both ends' egress: each direction gets that rate.
        Its queue holds 100 ms of traffic; what does not fit is dropped, as at a narrow
        link's router."""
        if rate_mbit <= 0:
            raise ValueError(f"rate: got {rate_mbit} Mbit/s, must be > 0")
        spec = ["tbf", "rate", f"{rate_mbit:g}mbit", "burst", "32kbit", "latency", "100ms"]
        _run("tc", "qdisc", "replace", "dev", self.host_if, "root", *spec)
        _run("ip", "netns", "exec", self.name, "tc", "qdisc", "replace", "dev", self.ns_if,
             "root", *spec)

    def clear(self) -> None:
        """Remove every fault: the link is as `create` left it."""
        if self._chains:
            for side in ("root", "ns"):
                self._iptables(side, "-F", self.chain)
        _quiet("tc", "qdisc", "del", "dev", self.host_if, "root")
        _quiet("ip", "netns", "exec", self.name, "tc", "qdisc", "del", "dev", self.ns_if,
               "root")


def make_host(index: int, *, subnet: str = SUBNET, tag: str | None = None) -> Host:
    """The `index`-th host's names and addresses (nothing is created yet); `tag` (default
    this process's id) keeps two processes' hosts apart."""
    tag = tag or str(os.getpid() % 100000)
    return Host(name=f"hnf{tag}-{index}", host_if=f"hnf{tag}h{index}",
                host_ip=f"{subnet}.{index}.1", ns_if=f"hnf{tag}n{index}",
                ns_ip=f"{subnet}.{index}.2", chain=f"HNF{tag}-{index}")


@contextlib.contextmanager
def hosts(count: int, *, subnet: str = SUBNET, first: int = 1) -> Iterator[list[Host]]:
    """`count` namespaced hosts (indices `first`, `first` + 1, …), removed with their chains
    and links however the body ends."""
    made = [make_host(i, subnet=subnet) for i in range(first, first + count)]
    with all_started(made, Host.create, Host.remove):
        yield made
