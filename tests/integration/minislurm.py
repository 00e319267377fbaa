"""A real Slurm cluster on one machine, for tests: munged, MariaDB, slurmdbd and slurmctld on
this host, and one slurmd per "host" (hercs-n1, hercs-n2) in its own namespaces on a bridge.
All state lives under one temporary folder; `stop()` ends every daemon it started (by pid) and
removes the namespaces and the bridge; `problem()` says why none can run here. Only this module
knows the cluster's layout (docs/CLUSTER.md §8).
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from hercs.apps.launch.router import free_port

BINARIES = ("munged", "mariadbd", "mariadb-install-db", "mariadb", "slurmdbd", "slurmctld",
            "slurmd", "sbatch", "sacct", "sacctmgr", "scontrol", "scancel", "sinfo", "srun",
            "ip", "unshare", "nsenter")
NET = "10.124.0"
CLUSTER = "hercs"
START_TIMEOUT_S = 60.0


def problem() -> str | None:
    """Why a mini cluster cannot run here, or None."""
    if os.geteuid() != 0:
        return f"a Slurm cluster in network namespaces needs root; this is uid {os.geteuid()}"
    missing = [b for b in BINARIES if shutil.which(b) is None]
    if missing:
        return (f"{', '.join(missing)} not installed (`make slurm` installs Debian's "
                "slurm-wlm, slurmdbd, munge and mariadb-server)")
    if subprocess.run(["ip", "-o", "addr", "show", "to", f"{NET}.0/24"], capture_output=True,
                      text=True).stdout.strip():
        return f"{NET}.0/24 is already in use on this host; not touching it"
    return None


def _run(*argv: str, **kw: object) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(list(argv), capture_output=True, text=True, **kw)  # type: ignore
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: exit {done.returncode}: "
                           f"{(done.stderr or done.stdout).strip()}")
    return done


@dataclass
class MiniSlurm:
    nodes: tuple[str, ...] = ("hercs-n1", "hercs-n2")
    cpus: int = 2
    """CPUs each node declares (they share this machine's cores)."""
    root: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="hs-")))
    procs: list[subprocess.Popen[bytes]] = field(default_factory=list)
    slurmds: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    """Each node's slurmd now (the one `bring_up` started last)."""
    _tag: str = field(default_factory=lambda: str(os.getpid() % 100000))

    @property
    def conf(self) -> Path:
        return self.root / "slurm.conf"

    @property
    def env(self) -> dict[str, str]:
        """The environment the client commands (sbatch, sacct, scontrol) need."""
        return dict(os.environ, SLURM_CONF=str(self.conf))

    def ns(self, node: str) -> str:
        return f"{node}-{self._tag}"

    def addr(self, i: int) -> str:
        return f"{NET}.{11 + i}"

    # ------------------------------------------------------------------ start

    def start(self) -> MiniSlurm:
        try:
            self._munge()
            self._mariadb()
            self._write_conf()
            self._slurmdbd()
            self._network()
            self._slurmctld()
            for i, node in enumerate(self.nodes):
                self._slurmd(i, node)
            self._wait_idle()
        except BaseException:
            self.stop()
            raise
        return self

    def _spawn(self, name: str, argv: list[str]) -> subprocess.Popen[bytes]:
        log = (self.root / f"{name}.out").open("wb")
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, env=self.env,
                                start_new_session=True)
        log.close()
        self.procs.append(proc)
        return proc

    def _wait(self, what: str, check: object, proc: subprocess.Popen[bytes] | None = None,
              log: str | None = None, timeout_s: float = START_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout_s
        while not check():  # type: ignore[operator]
            if proc is not None and proc.poll() is not None:
                tail = (self.root / log).read_text()[-3000:] if log else ""
                raise RuntimeError(f"{what}: exited {proc.returncode}\n{tail}")
            if time.monotonic() > deadline:
                tail = (self.root / log).read_text()[-3000:] if log else ""
                raise RuntimeError(f"{what}: not ready after {timeout_s:g} s\n{tail}")
            time.sleep(0.2)  # daemons announce readiness only by answering: poll them

    def _munge(self) -> None:
        key = self.root / "munge.key"
        key.write_bytes(os.urandom(1024))
        key.chmod(0o400)
        self.root.chmod(0o711)
        self.munge_socket = self.root / "munge.sock"
        self._spawn("munged", ["munged", "--foreground", "--force", f"--key-file={key}",
                               f"--socket={self.munge_socket}",
                               f"--pid-file={self.root / 'munged.pid'}",
                               f"--seed-file={self.root / 'munged.seed'}",
                               f"--log-file={self.root / 'munged.log'}"])
        self._wait("munged", self.munge_socket.exists, self.procs[-1], "munged.out")

    def _mariadb(self) -> None:
        data = self.root / "mysql"
        _run("mariadb-install-db", "--no-defaults", f"--datadir={data}", "--user=root",
             "--auth-root-authentication-method=socket", "--skip-test-db")
        self.db_port = free_port()
        self.db_socket = self.root / "mysql.sock"
        proc = self._spawn("mariadbd", [
            "mariadbd", "--no-defaults", f"--datadir={data}", "--user=root",
            f"--socket={self.db_socket}", "--bind-address=127.0.0.1", f"--port={self.db_port}",
            f"--pid-file={self.root / 'mysql.pid'}", "--skip-log-bin",
            "--innodb-buffer-pool-size=16M", "--innodb-log-file-size=8M"])
        self._wait("mariadbd", self.db_socket.exists, proc, "mariadbd.out")
        _run("mariadb", f"--socket={self.db_socket}", "-e",
             "CREATE USER 'slurm'@'127.0.0.1' IDENTIFIED BY 'hercs';"
             "GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';")

    def _write_conf(self) -> None:
        self.dbd_port = free_port()
        self.ctld_port = free_port()
        (self.root / "state").mkdir()
        dbd = self.root / "slurmdbd.conf"
        dbd.write_text("\n".join([
            "AuthType=auth/munge", f"AuthInfo=socket={self.munge_socket}",
            "DbdHost=localhost", "DbdAddr=127.0.0.1", f"DbdPort={self.dbd_port}",
            "SlurmUser=root", f"PidFile={self.root / 'slurmdbd.pid'}",
            f"LogFile={self.root / 'slurmdbd.log'}", "DebugLevel=info",
            "StorageType=accounting_storage/mysql", "StorageHost=127.0.0.1",
            f"StoragePort={self.db_port}", "StorageUser=slurm", "StoragePass=hercs",
            "StorageLoc=slurm_acct_db", ""]))
        dbd.chmod(0o600)
        nodes = [f"NodeName={n} NodeHostname={n} NodeAddr={self.addr(i)} CPUs={self.cpus} "
                 "State=UNKNOWN" for i, n in enumerate(self.nodes)]
        self.conf.write_text("\n".join([
            f"ClusterName={CLUSTER}", f"SlurmctldHost=hs-ctl({NET}.1)",
            f"SlurmctldPort={self.ctld_port}", "SlurmdPort=6818",
            "AuthType=auth/munge", f"AuthInfo=socket={self.munge_socket},cred_expire=10",
            "CredType=cred/munge", "SlurmUser=root", "SlurmdUser=root",
            f"StateSaveLocation={self.root / 'state'}",
            f"SlurmdSpoolDir={self.root}/spool-%n", f"SlurmctldPidFile={self.root}/ctld.pid",
            f"SlurmdPidFile={self.root}/slurmd-%n.pid",
            f"SlurmctldLogFile={self.root}/slurmctld.log",
            f"SlurmdLogFile={self.root}/slurmd-%n.log", "SlurmctldDebug=info",
            "SlurmdDebug=info", "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none",
            "JobAcctGatherType=jobacct_gather/linux", "JobAcctGatherFrequency=30",
            "AccountingStorageType=accounting_storage/slurmdbd",
            "AccountingStorageHost=127.0.0.1", f"AccountingStoragePort={self.dbd_port}",
            # the munge socket of connections to slurmdbd (AuthInfo covers the others)
            f"AccountingStoragePass={self.munge_socket}",
            "MpiDefault=none", "MailProg=/bin/true", "SwitchType=switch/none",
            # heterogeneous jobs start from the backfill scheduler: every 2 s, not 30
            "SchedulerType=sched/backfill", "SchedulerParameters=bf_interval=2",
            "SelectType=select/cons_tres", "SelectTypeParameters=CR_CPU",
            "ReturnToService=2", "KillWait=10", "MinJobAge=600", "InactiveLimit=0",
            "SlurmdTimeout=60", "MessageTimeout=20", "JobRequeue=1",
            *nodes,
            f"PartitionName=main Nodes={','.join(self.nodes)} Default=YES MaxTime=INFINITE "
            "State=UP OverSubscribe=NO", ""]))

    def _slurmdbd(self) -> None:
        # slurmdbd reads slurmdbd.conf beside $SLURM_CONF
        proc = self._spawn("slurmdbd", ["slurmdbd", "-D"])

        def answers() -> bool:
            return subprocess.run(["sacctmgr", "-n", "list", "cluster"], capture_output=True,
                                  env=self.env, timeout=20).returncode == 0

        self._wait("slurmdbd", answers, proc, "slurmdbd.out")
        _run("sacctmgr", "-i", "add", "cluster", CLUSTER, env=self.env)

    def _network(self) -> None:
        self.bridge = f"hsb{self._tag}"
        _run("ip", "link", "add", self.bridge, "type", "bridge")
        _run("ip", "addr", "add", f"{NET}.1/24", "dev", self.bridge)
        _run("ip", "link", "set", self.bridge, "up")
        self.hosts = self.root / "hosts"
        self.hosts.write_text("127.0.0.1 localhost\n" + f"{NET}.1 hs-ctl\n" + "".join(
            f"{self.addr(i)} {n}\n" for i, n in enumerate(self.nodes)))
        for i, node in enumerate(self.nodes):
            ns, host_if = self.ns(node), f"hs{self._tag}h{i}"
            _run("ip", "netns", "add", ns)
            _run("ip", "link", "add", host_if, "type", "veth", "peer", "name", "eth0",
                 "netns", ns)
            _run("ip", "link", "set", host_if, "master", self.bridge)
            _run("ip", "link", "set", host_if, "up")
            _run("ip", "-n", ns, "addr", "add", f"{self.addr(i)}/24", "dev", "eth0")
            _run("ip", "-n", ns, "link", "set", "eth0", "up")
            _run("ip", "-n", ns, "link", "set", "lo", "up")

    def _slurmctld(self) -> None:
        # on this host's network, under the controller's own host name (slurmctld checks it)
        proc = self._spawn("slurmctld", [
            "unshare", "--uts", "sh", "-c",
            f'hostname hs-ctl && exec slurmctld -D -i -f "{self.conf}"'])

        def answers() -> bool:
            return subprocess.run(["scontrol", "ping"], capture_output=True, env=self.env,
                                  text=True, timeout=20).stdout.find("UP") >= 0

        self._wait("slurmctld", answers, proc, "slurmctld.log")

    def _slurmd(self, i: int, node: str) -> None:
        # The node's network namespace, and a mount and UTS namespace of its own: its
        # /etc/hosts and host name (not `ip netns exec`, whose fresh /sys hides the cgroup
        # mounts slurmd needs).
        spool = self.root / f"spool-{node}"
        spool.mkdir(exist_ok=True)  # a node brought up again keeps its spool
        self.slurmds[node] = self._spawn(f"slurmd-{node}", [
            "nsenter", f"--net=/run/netns/{self.ns(node)}", "unshare", "--mount", "--uts",
            "sh", "-c", f'mount --bind "{self.hosts}" /etc/hosts && hostname {node} && '
                        f'exec slurmd -D -N {node} -f "{self.conf}"'])

    def _wait_idle(self, timeout_s: float = START_TIMEOUT_S) -> None:
        def idle() -> bool:
            out = subprocess.run(["sinfo", "-h", "-N", "-o", "%N %t"], capture_output=True,
                                 text=True, env=self.env, timeout=20).stdout
            states = dict(line.split() for line in out.splitlines() if line.strip())
            return all(states.get(n) == "idle" for n in self.nodes)

        self._wait("slurmd on every node", idle, None, "slurmctld.log", timeout_s)

    # ------------------------------------------------------------------ node failures

    def take_down(self, node: str) -> list[int]:
        """The node dies at once: every process in its network namespace (its slurmd, the
        steps' slurmstepd and tasks) gets SIGKILL, as at a power loss. Returns their pids."""
        out = subprocess.run(["ip", "netns", "pids", self.ns(node)], capture_output=True,
                             text=True, check=True).stdout
        pids = [int(p) for p in out.split()]
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        slurmd = self.slurmds.get(node)
        if slurmd is not None and slurmd.pid in pids:
            slurmd.wait(30)  # reaped: `restore` tells a dead slurmd by its exit status
        return pids

    def node_state(self, node: str) -> str:
        """`sinfo`'s short state of `node` (idle, alloc, down*, ...)."""
        out = subprocess.run(["sinfo", "-h", "-n", node, "-o", "%t"], capture_output=True,
                             text=True, env=self.env, timeout=20).stdout
        return out.strip()

    def bring_up(self, node: str) -> None:
        """Start the node's slurmd again (ReturnToService=2: it returns to service when it
        registers)."""
        self._slurmd(self.nodes.index(node), node)

    def restore(self, timeout_s: float = 180.0) -> None:
        """Back to the state `start()` left: every job cancelled, every node's slurmd running
        (one a test took down and did not bring up is started again) and every node idle, so
        that a test that failed half-way does not fail the tests after it. `timeout_s` bounds
        the wait for idle: a cancelled job's processes get KillWait (10 s) to end, and a node
        that slurmctld marked down returns when its new slurmd registers."""
        user = pwd.getpwuid(os.geteuid()).pw_name  # the tests' jobs are all this user's
        subprocess.run(["scancel", "--user", user], capture_output=True, env=self.env,
                       timeout=20)
        for i, node in enumerate(self.nodes):
            if self.slurmds[node].poll() is not None:
                self._slurmd(i, node)
        self._wait_idle(timeout_s)

    # ------------------------------------------------------------------ stop

    def stop(self) -> None:
        # A job still running has processes in the nodes' namespaces (slurmstepd, srun, the
        # run): they would outlive the daemons and the deleted namespaces' names.
        for node in getattr(self, "nodes", []):
            with contextlib.suppress(subprocess.CalledProcessError, OSError):
                self.take_down(node)
        for proc in reversed(self.procs):  # slurmds, slurmctld, slurmdbd, mariadbd, munged
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGTERM)
                try:
                    proc.wait(15)
                except subprocess.TimeoutExpired:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
        for node in self.nodes:
            subprocess.run(["ip", "netns", "del", self.ns(node)], capture_output=True)
        if getattr(self, "bridge", None):
            subprocess.run(["ip", "link", "del", self.bridge], capture_output=True)

    def logs(self) -> str:
        """The daemons' logs' tails, for a failure message."""
        parts = []
        for path in sorted(self.root.glob("*.log")):
            parts.append(f"--- {path.name}\n{path.read_text(errors='replace')[-2000:]}")
        return "\n".join(parts)
