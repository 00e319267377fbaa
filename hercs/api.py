"""The Python API: a run directory's policy, metrics, episodes and config, no service running.

Re-exported by the `hercs` package (`hercs.load_policy`, `read_metrics`, `read_episodes`,
`load_config`). Arrays are numpy; errors are `HercsError`s naming the file and what to do.
Torch, the episode log and the config are imported inside the calls, so `import hercs` stays light.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

import numpy as np

from hercs.errors import HercsError
from hercs.wire.episode import EpisodeData

if TYPE_CHECKING:
    from hercs.config import HercsConfig
    from hercs.rl.task_registry import TaskSpec
    from hercs.run.policy_files import LoadedPolicy

OBSERVATION_KEYS = ("observation", "desired_goal")
"""What `act` reads of the env's observation dict (`achieved_goal` may be there too)."""

MetricValue = int | float | str | tuple[int | float, ...] | dict[str, int] | None
"""A parsed metrics.csv cell: a number, a ';'-separated list of numbers (cluster_sizes,
cluster_share), `reason:count` pairs (rejects), text, or None where the cell is empty."""

LIST_COLUMNS = frozenset({"cluster_sizes", "cluster_share"})
COUNT_COLUMNS = frozenset({"rejects"})


class ObservationError(HercsError, ValueError):
    """An observation given to `TrainedPolicy.act` is not one of the policy's task."""


class MissingPackage(HercsError, ImportError):
    """An optional package a call needs is not installed; the message says which."""


class TrainedPolicy:
    """A run's trained policy: μ(o, g) with its normalisers, as the run's evaluator acts.

    Made by `load_policy`. `act` is deterministic unless asked to explore."""

    def __init__(self, loaded: LoadedPolicy, *, seed: int | None = None) -> None:
        self._policy = loaded.policy()
        self._rng = np.random.default_rng(seed)
        self.config: HercsConfig = loaded.config
        """The run's resolved config."""
        self.epoch: int = loaded.epoch
        """The epoch at whose end these weights were taken."""
        self.source: Path = loaded.source
        """The checkpoint file read."""
        self.weights_version: int = loaded.weights.version

    @property
    def spec(self) -> TaskSpec:
        """The task: `obs_dim`, `goal_dim`, `action_dim`, `max_action`, `env_id`, …"""
        return self.config.task.spec

    def act(self, observation: Mapping[str, Any], *, explore: bool = False,
            rng: np.random.Generator | None = None) -> np.ndarray:
        """Action(s) for the env's observation dict, float32 in [-max_action, max_action].

        `observation["observation"]` is (obs_dim,) or (n, obs_dim), `["desired_goal"]`
        (goal_dim,) or (n, goal_dim); returns (action_dim,) or (n, action_dim). With
        `explore=False` (the default) this is μ(o, g), the run's evaluator's action. With
        `explore=True`, the actors' exploration (Gaussian noise and random actions) drawn
        from `rng`, or from a generator seeded by `load_policy(seed=...)`.
        """
        o, g = self._arrays(observation)
        return self._policy.act(o, g, explore=explore,
                                rng=rng if rng is not None else self._rng)

    def _arrays(self, observation: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        if not isinstance(observation, Mapping):
            raise ObservationError(
                f"act: got {type(observation).__name__}, need the env's observation dict "
                f"with keys {list(OBSERVATION_KEYS)}")
        missing = [k for k in OBSERVATION_KEYS if k not in observation]
        if missing:
            raise ObservationError(f"act: the observation has no {missing} (keys: "
                                   f"{sorted(observation)}); pass the env's observation dict")
        spec = self.spec
        arrays = []
        for key, size in zip(OBSERVATION_KEYS, (spec.obs_dim, spec.goal_dim), strict=True):
            value = np.asarray(observation[key], dtype=np.float64)
            if value.ndim not in (1, 2) or value.shape[-1] != size:
                raise ObservationError(
                    f"act: observation[{key!r}] has shape {value.shape}; task {spec.name} "
                    f"needs ({size},) for one observation or (n, {size}) for n")
            arrays.append(value)
        o, g = arrays
        if o.ndim != g.ndim or o.shape[:-1] != g.shape[:-1]:
            raise ObservationError(
                f"act: observation['observation'] {o.shape} and observation['desired_goal'] "
                f"{g.shape} do not match: give both single (1-d) or both with n rows")
        return o, g

    def __repr__(self) -> str:
        return (f"TrainedPolicy(run={self.config.run.name!r}, task={self.spec.name!r}, "
                f"method={self.config.run.method!r}, epoch={self.epoch}, "
                f"source={str(self.source)!r})")


def load_policy(run_dir: str | os.PathLike[str], checkpoint: str = "best", *,
                seed: int | None = None, task: str | None = None,
                trust_task: bool = False) -> TrainedPolicy:
    """The trained policy of a run directory.

    A run of a user's own environment (`package.module:factory`) loads only with `task` set
    to that name, or `trust_task=True`: hercs imports no code because a file names it
    (hercs.rl.code_names; a `ConfigError` says so).

    `checkpoint`: 'best' (checkpoints/best.pt, the best-evaluated epoch), 'latest'
    (learner.pt, the last epoch end), 'epoch-N' (epoch-NNNN.pt) or a .pt file's path.
    `seed` seeds the generator of `act(..., explore=True)`. Raises `RunDirError` for a folder
    that is not a run or a checkpoint it does not hold (naming those it does),
    `CheckpointError` for a file that does not load."""
    from hercs.rl import code_names
    from hercs.run.policy_files import read_policy

    for name in (task, code_names.ANY if trust_task else None):
        if name:
            code_names.trust_task(name)
    return TrainedPolicy(read_policy(run_dir, checkpoint), seed=seed)


@dataclass(frozen=True)
class Metrics:
    """A run's metrics.csv: one row per evaluated epoch, cells parsed (`MetricValue`).

    Iterate for the rows (dicts by column); take a column by name, `metrics["success_rate"]`
    (`__getitem__`), or as floats, `metrics.column("success_rate")`; or the whole table as a
    pandas DataFrame, `metrics.to_pandas()`. The columns are hercs.run.metrics.METRICS_COLUMNS
    for a run of this version (older runs may have fewer)."""

    path: Path
    columns: tuple[str, ...]
    rows: tuple[dict[str, MetricValue], ...]

    def __len__(self) -> int:
        return len(self.rows)

    def __iter__(self) -> Iterator[dict[str, MetricValue]]:
        return iter(self.rows)

    @overload
    def __getitem__(self, name: str) -> np.ndarray | list[MetricValue]: ...
    @overload
    def __getitem__(self, name: int) -> dict[str, MetricValue]: ...
    @overload
    def __getitem__(self, name: slice) -> tuple[dict[str, MetricValue], ...]: ...

    def __getitem__(self, name: str | int | slice) -> Any:
        """Column `name`, one value per row: a numpy array where every cell is a number
        (int64 where all are integers and none is empty, else float64 with nan where a row
        has none), else a list of the parsed cells (cluster_sizes' tuples, rejects' dicts).
        An int or a slice takes rows instead: `metrics[-1]` is the last epoch's row."""
        if not isinstance(name, str):
            if isinstance(name, int | slice) and not isinstance(name, bool):
                return self.rows[name]
            raise TypeError(f"metrics[{name!r}]: give a column name (str), e.g. "
                            "metrics['success_rate'], or a row number, metrics[-1]")
        self._check_column(name)
        values = [row.get(name) for row in self.rows]
        if all(isinstance(v, int) for v in values):
            return np.array(values, dtype=np.int64)
        if all(v is None or isinstance(v, int | float) for v in values):
            return self.column(name)
        return values

    def _check_column(self, name: str) -> None:
        if not isinstance(name, str):
            raise TypeError(f"metrics[{name!r}]: give a column name (str), e.g. "
                            "metrics['success_rate'], or a row number, metrics[-1]")
        if name not in self.columns:
            raise KeyError(f"{self.path}: no column {name!r}; columns: {list(self.columns)}")

    def to_pandas(self) -> Any:
        """The table as a pandas DataFrame (one row per epoch, the file's column order; list
        columns hold tuples). Raises `MissingPackage` where pandas is not installed."""
        try:
            import pandas as pd  # type: ignore[import-untyped]  # optional, no stubs
        except ImportError:
            raise MissingPackage("Metrics.to_pandas needs pandas, which this Python lacks: "
                                 "pip install pandas (or take columns as arrays: "
                                 "metrics['success_rate'])") from None
        return pd.DataFrame(list(self.rows), columns=list(self.columns))

    def column(self, name: str) -> np.ndarray:
        """A numeric column as float64, nan where a row has no value."""
        self._check_column(name)
        values = [row.get(name) for row in self.rows]
        bad = [v for v in values if v is not None and not isinstance(v, int | float)]
        if bad:
            raise TypeError(f"{self.path}: column {name!r} is not numeric (e.g. {bad[0]!r}); "
                            "read it from the rows")
        return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def read_metrics(run_dir: str | os.PathLike[str]) -> Metrics:
    """`run_dir/metrics.csv` (or a metrics.csv file given directly), numbers parsed."""
    from hercs.run.metrics import read_table
    from hercs.run.rundir import METRICS, RunDir, require_run_dir

    path = Path(run_dir)
    if not (path.is_file() and path.suffix == ".csv"):
        path = RunDir(require_run_dir(path, needs=(METRICS,))).metrics
    header, table = read_table(path)
    rows = tuple({key: _cell(key, value) for key, value in row.items() if key is not None}
                 for row in table)
    return Metrics(path=path, columns=tuple(header), rows=rows)


def _cell(column: str, text: str | None) -> MetricValue:
    if text is None or text == "":
        return None
    if column in COUNT_COLUMNS:
        pairs = (item.rpartition(":") for item in text.split(";") if item)
        return {reason: int(count) for reason, _, count in pairs}
    if column in LIST_COLUMNS:
        return tuple(_number(item) for item in text.split(";") if item)
    try:
        return _number(text)
    except ValueError:
        return text


def _number(text: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        return float(text)


@dataclass
class LoggedEpisode(EpisodeData):
    """An episode as the episode log holds it: `EpisodeData` (obs, ag, g, actions, actor_id,
    seq, success, policy_version) with its id and the run and task it was logged for.

    Shapes, T = the task's episode_steps: obs (T+1, obs_dim), ag (T+1, goal_dim),
    g (T, goal_dim), actions (T, action_dim), all float32."""

    id: int = field(kw_only=True)
    """The episode id the replay gave it (MCAP sequence), increasing across segments."""
    run: str = field(default="", kw_only=True)
    task: str = field(default="", kw_only=True)


def read_episodes(run_dir: str | os.PathLike[str], *, ids: Iterable[int] | None = None,
                  last: int | None = None) -> Iterator[LoggedEpisode]:
    """The episodes of a run's log in the order logged, across all its segments
    (episodes.000.mcap, …, episodes.mcap); also a single .mcap file.

    `ids`: only these episode ids; `last`: only the last N (of those selected by `ids`, if
    given). Only the selected episodes are decoded. Works while the run writes its log and on
    a log whose writer was killed (up to its last complete record). A bounded log
    (`replay.log_max_bytes`, the default) deletes its oldest segments once their episodes
    have left the buffer: it starts at a later id then, and ids before it are not there."""
    from hercs.proto import hercs_pb2 as pb
    from hercs.run.rundir import require_run_dir
    from hercs.run.runlog import LIVE_NAME, TOPIC_EPISODES, read_messages
    from hercs.wire.codec import msg_to_episode

    path = Path(run_dir)
    if not path.is_file():
        path = require_run_dir(path, needs=(LIVE_NAME,))
    if last is not None and last < 0:
        raise ValueError(f"read_episodes: last={last}, must be >= 0")
    wanted = None if ids is None else {int(i) for i in ids}
    messages = (m for m in read_messages(path, [TOPIC_EPISODES])
                if wanted is None or m.sequence in wanted)
    selected: Iterable[Any] = messages if last is None else deque(messages, maxlen=last)
    for message in selected:
        msg = message.decode_as(pb.Episode)
        data = msg_to_episode(msg)
        yield LoggedEpisode(obs=data.obs.copy(), ag=data.ag.copy(), g=data.g.copy(),
                            actions=data.actions.copy(), actor_id=data.actor_id, seq=data.seq,
                            success=data.success, policy_version=data.policy_version,
                            id=int(message.sequence), run=msg.run, task=msg.task)


def load_config(source: str | os.PathLike[str] | None = None,
                overrides: Sequence[str] = ()) -> HercsConfig:
    """A validated config: the defaults (`source` None), a YAML file (partial: the rest
    defaults) or a run directory's config.yaml; then `overrides` as `hercs --set` takes them
    (`"ddpg.lr_actor=5e-4"`). Raises `ConfigError` naming the file, field and value."""
    from hercs.config import HercsConfig, apply_overrides, load_yaml
    from hercs.run.rundir import RunDir, require_run_dir

    if source is None:
        config = HercsConfig()
    elif Path(source).is_dir():
        config = load_yaml(RunDir(require_run_dir(source)).config)
    else:
        config = load_yaml(Path(source))
    return apply_overrides(config, list(overrides)) if overrides else config
