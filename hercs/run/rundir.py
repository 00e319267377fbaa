"""A run directory (`runs/<run>/`, made by `hercs up`) and its one owner, `RunDir(path)`: every
name a run directory holds (the table is docs/DESIGN.md §6) and checks whose errors say what a
folder lacks and what to do. No other module joins a run directory's file names.

The checkpoint names repeat `hercs.learner.checkpoint`'s (a unit test keeps them equal), so
readers in the library layer need not import the learner.
"""

from __future__ import annotations

import difflib
import os
import re
from datetime import datetime
from pathlib import Path

from hercs.config import RunConfig
from hercs.errors import HercsError
from hercs.run.metrics import recorded_epochs

CONFIG = "config.yaml"
METRICS = "metrics.csv"
CHECKPOINTS = "checkpoints"
LOGS = "logs"
TENSORBOARD = "tensorboard"
TRACKING = "tracking.json"
"""Which tracker runs (W&B, MLflow) this run continues, and the epochs each was sent."""
LATEST = "learner.pt"
BEST = "best.pt"
EPOCH_FILE = re.compile(r"^epoch-(\d+)\.pt$")
ROUTER = "router.json"
SLURM = "slurm"
LOCK = "owner.lock"
PREVIOUS = "previous"
DONE_RECORD = "bench_done.json"
"""What `hercs sweep` records of a finished run: its commit, machine, command, wall time."""
ROUTER_LOG = "router.log"
"""`logs/router.log`: what the Zenoh router embedded in `hercs up` logs itself."""
LIVE_NAME = "episodes.mcap"
"""The episode log's live segment (`hercs.run.runlog`); retired ones are episodes.NNN.mcap."""
SEGMENT_RE = re.compile(r"^episodes\.(\d+)\.mcap$")
BEFORE_START = frozenset({SLURM, LOCK})
"""What a run directory may hold before its run first starts (a fresh `hercs up` refuses a
folder holding anything else: its replay would load an old episode log)."""

CHECKPOINT_NAMES = "best, latest, epoch-N or a .pt file's path"
"""What a checkpoint argument may be (`hercs eval --checkpoint`, `hercs.load_policy`)."""

WHAT_A_RUN_HOLDS = ("config.yaml, metrics.csv, episodes.mcap and checkpoints/, which "
                    "`hercs up` writes into runs/<run>/")

NOT_YET = {
    METRICS: "the learner writes its first row when epoch 1 has been evaluated; wait for "
             "that, or look at a finished run",
    LIVE_NAME: "the replay writes it from the run's first episode on; wait for the run to "
               "start, or look at another run",
}
"""Why a run directory may lack a file, and what to do, by file name."""


class RunDir:
    """A run directory: where each thing a run keeps is (the table above). Every path into a
    run directory is made here, so that a file has one name in one place.

    `RunDir(path)` checks nothing; `require_run_dir` checks a folder is a run's."""

    __slots__ = ("path",)

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def __fspath__(self) -> str:
        return os.fspath(self.path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, RunDir) and other.path == self.path

    def __hash__(self) -> int:
        return hash(self.path)

    @property
    def name(self) -> str:
        """The run's name (the folder's)."""
        return self.path.name

    @property
    def config(self) -> Path:
        return self.path / CONFIG

    @property
    def metrics(self) -> Path:
        return self.path / METRICS

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS

    def checkpoint(self, name: str | None = None) -> Path:
        """The policy file `name` names: best, latest, epoch-N or a path (`checkpoint_path`)."""
        return checkpoint_path(self.path, name)

    @property
    def logs(self) -> Path:
        return self.path / LOGS

    def log(self, ident: str) -> Path:
        """`logs/<ident>.log`: a service's log (its id, e.g. replay-0), or the router's."""
        return self.logs / f"{ident}.log"

    @property
    def router_log(self) -> Path:
        return self.logs / ROUTER_LOG

    @property
    def tensorboard(self) -> Path:
        return self.path / TENSORBOARD

    @property
    def tracking(self) -> Path:
        return self.path / TRACKING

    @property
    def router(self) -> Path:
        """router.json, while the run's `hercs up` runs (`read_router`)."""
        return self.path / ROUTER

    @property
    def lock(self) -> Path:
        return self.path / LOCK

    @property
    def previous(self) -> Path:
        return self.path / PREVIOUS

    @property
    def slurm(self) -> Path:
        return self.path / SLURM

    @property
    def episode_log(self) -> Path:
        """The episode log's live segment, episodes.mcap."""
        return self.path / LIVE_NAME

    def segment(self, number: int) -> Path:
        """A retired segment of the episode log: episodes.NNN.mcap."""
        return self.path / f"episodes.{number:03d}.mcap"

    def _numbered_segments(self) -> list[tuple[int, Path]]:
        """The retired segments with their numbers, in number order."""
        return sorted(
            (int(m.group(1)), p) for p in self.path.iterdir()
            if (m := SEGMENT_RE.match(p.name)) is not None
        ) if self.path.is_dir() else []

    def log_segments(self) -> list[Path]:
        """The episode log's segments in the order they were written: episodes.000.mcap, …,
        then episodes.mcap (if there is one)."""
        paths = [p for _, p in self._numbered_segments()]
        if self.episode_log.exists():
            paths.append(self.episode_log)
        return paths

    def next_segment(self) -> Path:
        """The name the live segment takes when it is sealed: one number above the highest."""
        numbered = self._numbered_segments()
        return self.segment(numbered[-1][0] + 1 if numbered else 0)


class RunDirError(HercsError):
    """A folder is not a run directory, or lacks what the caller needs from it; the message
    names the folder, what is missing and what to do."""


def run_dir_of(run: RunConfig) -> Path:
    """`run.run_dir/run.name`: where every process of the run reads and writes its files."""
    return Path(run.run_dir) / run.name


def epoch_file(epoch: int) -> str:
    """The name of the policy file kept every `training.checkpoint_every` epochs."""
    return f"epoch-{epoch:04d}.pt"


def is_run_dir(path: str | os.PathLike[str]) -> bool:
    """Whether `path` is a folder holding a run's config.yaml."""
    return (Path(path) / CONFIG).is_file()


def has_episode_log(path: str | os.PathLike[str]) -> bool:
    path = Path(path)
    return (path / LIVE_NAME).exists() or any(SEGMENT_RE.match(p.name) for p in path.iterdir())


def require_run_dir(path: str | os.PathLike[str], *, needs: tuple[str, ...] = ()) -> Path:
    """`path` as a Path if it is a run directory holding every file named in `needs` (names
    in this module, or LIVE_NAME for the episode log in any segment); else `RunDirError`."""
    path = Path(path)
    if not path.exists():
        raise RunDirError(f"{path}: no such folder; give a run directory, the folder "
                          f"`hercs up` made as runs/<run>/{_nearby_runs(path)}")
    if not path.is_dir():
        raise RunDirError(f"{path}: a file, not a run directory; give the folder that holds "
                          f"{WHAT_A_RUN_HOLDS}")
    if not is_run_dir(path):
        inside = _runs_in(path)
        hint = (f"; it holds run directories: {_listed(inside)}; give one of them" if inside
                else _nearby_runs(path))
        raise RunDirError(f"{path}: not a run directory: it has no {CONFIG} (a run directory "
                          f"holds {WHAT_A_RUN_HOLDS}){hint}")
    for name in needs:
        present = has_episode_log(path) if name == LIVE_NAME else (path / name).exists()
        if not present:
            what = "episode log (episodes.mcap or episodes.NNN.mcap)" if name == LIVE_NAME \
                else name
            trained = recorded_count(path)
            if trained:
                raise RunDirError(
                    f"{path}: this run has no {what}, and never will here: its {METRICS} "
                    f"records {trained} trained epochs, so the run wrote its files where it "
                    f"trained, and this folder is a copy without them ({COPY_HOLDS}); use the "
                    "folder where it trained, or a run that has one")
            raise RunDirError(f"{path}: this run has no {what} yet; "
                              f"{NOT_YET.get(name, 'was it made by this version of hercs?')}")
    return path


COPY_HOLDS = "a copied or committed run often keeps only config.yaml and metrics.csv"


def recorded_count(run_dir: Path) -> int:
    """How many epochs `run_dir`'s metrics.csv records (0: none, no file or unreadable)."""
    try:
        return len(set(recorded_epochs(run_dir / METRICS)))
    except (OSError, ValueError):
        return 0


def _runs_in(folder: Path) -> list[str]:
    try:
        return sorted(p.name for p in folder.iterdir() if p.is_dir() and is_run_dir(p))
    except OSError:
        return []


def _listed(names: list[str], most: int = 6) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most
                                      else "")


def _nearby_runs(path: Path) -> str:
    """'; did you mean …?' or '; run directories in PARENT: …' from the folder above `path`,
    or else from the default run folder (runs/) beside it."""
    parent = path.parent
    runs = [name for name in _runs_in(parent) if name != path.name]
    if not runs:
        parent = parent / RunConfig.run_dir
        runs = _runs_in(parent)
    if not runs:
        return ""
    close = difflib.get_close_matches(path.name, runs, n=1)
    if close:
        return f"; did you mean {parent / close[0]}?"
    return f"; run directories in {parent}: {_listed(runs)}"


def checkpoint_path(run_dir: Path, checkpoint: str | None) -> Path:
    """The file a checkpoint argument names: 'best', 'latest', 'epoch-N' under
    `run_dir/checkpoints/`, or a path; None = best.pt if it exists, else learner.pt (what
    `hercs eval` loads by default)."""
    folder = run_dir / CHECKPOINTS
    if checkpoint is None:
        return folder / BEST if (folder / BEST).exists() else folder / LATEST
    if checkpoint == "best":
        return folder / BEST
    if checkpoint == "latest":
        return folder / LATEST
    if checkpoint.startswith("epoch-") and checkpoint[6:].isdigit():
        return folder / epoch_file(int(checkpoint[6:]))
    return Path(checkpoint)


def kept_checkpoints(run_dir: Path) -> dict[str, str]:
    """{file name: the name to ask for it by} of the checkpoints in `run_dir/checkpoints/`,
    best first, then latest, then by epoch."""
    folder = run_dir / CHECKPOINTS
    files = sorted(p.name for p in folder.glob("*.pt")) if folder.is_dir() else []
    kept = {name: {BEST: "best", LATEST: "latest"}.get(name, "") for name in files}
    for name in files:
        match = EPOCH_FILE.match(name)
        if match:
            kept[name] = f"epoch-{int(match[1])}"
    order = {BEST: 0, LATEST: 1}
    return dict(sorted(kept.items(), key=lambda item: (order.get(item[0], 2), item[0])))


def missing_checkpoint(run_dir: Path, checkpoint: str | None, path: Path) -> RunDirError:
    """The error for a checkpoint that `checkpoint_path` named and that does not exist: which
    one was asked for, which exist and what to do."""
    folder = run_dir / CHECKPOINTS
    if path.parent != folder:
        return RunDirError(f"checkpoint {path}: no such file; give {CHECKPOINT_NAMES}")
    asked = (f"best ({BEST}, the default) and no {LATEST}" if checkpoint is None
             else f"{checkpoint} ({path.name})")
    kept = kept_checkpoints(run_dir)
    trained = recorded_count(run_dir)
    if not kept and trained:
        where = "holds none" if folder.is_dir() else "does not exist"
        return RunDirError(
            f"{run_dir}: no checkpoint {asked}: {folder} {where}, though {METRICS} records "
            f"{trained} trained epochs: this folder is a copy of the run without its "
            f"checkpoints ({COPY_HOLDS}). Evaluate the folder where it trained, or give a "
            f"policy file (--checkpoint FILE.pt){_runs_with_policies(run_dir)}; its learning "
            f"curve is in {METRICS} (hercs plot {run_dir} -o fig.png)")
    if not kept:
        return RunDirError(
            f"{run_dir}: no checkpoint {asked} yet: {folder} holds none. {BEST} (best, the "
            f"best-evaluated epoch's policy) is written once the run's first epoch has been "
            f"evaluated, {LATEST} (latest) at every epoch end; wait for epoch 1 to finish "
            "(metrics.csv gets its row), or give another run")
    offers = ", ".join(f"{ask} ({name})" if ask else name for name, ask in kept.items())
    return RunDirError(f"{run_dir}: no checkpoint {asked}; {folder} holds {offers}: ask for "
                       f"one of those ({CHECKPOINT_NAMES})")


def _runs_with_policies(run_dir: Path, most: int = 3) -> str:
    """'; runs beside it with a policy: …' (the same run name up to its seed first), or ''."""
    parent = run_dir.resolve().parent
    cell = run_dir.resolve().name.rpartition("-s")[0]
    try:
        kept = sorted(p for p in parent.iterdir()
                      if p.is_dir() and p.name != run_dir.resolve().name
                      and (p / CHECKPOINTS / BEST).is_file())
    except OSError:
        return ""
    kept.sort(key=lambda p: p.name.rpartition("-s")[0] != cell)  # stable: the same cell first
    if not kept:
        return ""
    shown = [str(run_dir.parent / p.name) for p in kept[:most]]
    more = f" and {len(kept) - most} more" if len(kept) > most else ""
    return f"; runs beside it with a policy ({BEST}): {', '.join(shown)}{more}"


def aside_folder(run_dir: Path, now: datetime | None = None) -> Path:
    """A new `run_dir/previous/<YYYYmmdd-HHMMSS>[-n]` (not made yet) to set old files aside in:
    what would be replaced is moved there, never deleted."""
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    folder = run_dir / PREVIOUS / stamp
    n = 1
    while folder.exists():
        n += 1
        folder = run_dir / PREVIOUS / f"{stamp}-{n}"
    return folder


def holds_a_run(path: Path) -> bool:
    """Whether `path` holds anything of a started run (more than `BEFORE_START`)."""
    return path.is_dir() and any(p.name not in BEFORE_START for p in path.iterdir())
