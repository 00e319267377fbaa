"""What one series of `hercs plot` is: the runs that differ by their seed alone.

A series key is the method followed by every setting a run's config.yaml changes that makes it
another experiment (schedule, precision, a caller's variant, the policy-lag settings, EBP's ε,
the cluster share rule, the environment), "/"-joined; `method_label` says it compactly and
`choose` picks the few series a panel draws (docs/DESIGN.md §6, "Figures").
"""

from __future__ import annotations

import fnmatch
import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hercs.config import TrainingConfig
from hercs.config.algorithm import EPSILON_V1, ClusterConfig, default_energy_epsilon
from hercs.config.deploy import ActorConfig, LearnerConfig
from hercs.config.replay import ReplayConfig
from hercs.rl.methods import METHODS

METHOD_ORDER: tuple[str, ...] = tuple(METHODS)
METHOD_LABELS: dict[str, str] = {name: method.label for name, method in METHODS.items()}
ENV_VERSION_DEFAULT = "v4"
"""`task.env_version` of a run whose config.yaml has none (written before v1 existed)."""
EPSILON_UNMARKED = EPSILON_V1
"""EBP's ε that run names and keys leave unsaid: every run's until 2026-11-28, and v1's
default still. An EBP run with another (v4's default 1e-3 included) is marked `eps…`, so
that the runs made before v4's default changed keep their names; ε does nothing to HER and
HER-CS, whose runs are never marked."""
OTHER_CODE: dict[str, str] = {"authors-code": "authors' code"}
"""`training.schedule`s of runs another program made (studies.authors_peer runs the authors'
published code on our stack): whose they are, said where a label would say "ours"."""
MAX_SERIES = 6
"""Series one panel draws by default, the authors' curves included: past this they cover
one another; `--series` / `--all-series` draw others."""


@dataclass(frozen=True)
class PolicyLag:
    """The settings that let an asynchronous run's episodes be acted with older weights
    (docs/PERFORMANCE.md §2), in the order `lag=` keys and labels give them."""

    tolerance: float  # replay.rate_tolerance_updates
    prefetch: int  # learner.prefetch_depth
    queue: int  # actor.insert_queue
    bound: int  # training.max_policy_lag, -1: none

    def component(self) -> str:
        """The key's part: `lag=80,3,2,-1` ("=" is never in a sweep's variant name)."""
        return f"lag={self.tolerance:g},{self.prefetch},{self.queue},{self.bound}"


DEFAULT_LAG = PolicyLag(ReplayConfig().rate_tolerance_updates, LearnerConfig().prefetch_depth,
                        ActorConfig().insert_queue, TrainingConfig().max_policy_lag)
UNSAVED_LAG = {"prefetch_depth": 3, "insert_queue": 2, "max_policy_lag": -1}
"""What a resolved config.yaml saved before these settings existed (2026-11-25) ran with:
3 batches prefetched, 2 episodes queued per actor, no bound (docs/PERFORMANCE.md §2)."""


def policy_lag(config: dict[str, Any]) -> PolicyLag:
    """An asynchronous run's lag settings. A field that a saved config.yaml (one whose
    `replay` holds `rate_tolerance_updates`, as every run's does) lacks is the value it ran
    with (UNSAVED_LAG); a config written by hand, without it, has the defaults."""
    saved = "rate_tolerance_updates" in (config.get("replay") or {})

    def read(section: str, key: str, default: float) -> float:
        values = config.get(section) or {}
        return float(values.get(key, UNSAVED_LAG.get(key, default) if saved else default))

    return PolicyLag(read("replay", "rate_tolerance_updates", DEFAULT_LAG.tolerance),
                     int(read("learner", "prefetch_depth", DEFAULT_LAG.prefetch)),
                     int(read("actor", "insert_queue", DEFAULT_LAG.queue)),
                     int(read("training", "max_policy_lag", DEFAULT_LAG.bound)))


def marks_epsilon(method: str, energy_epsilon: float) -> bool:
    """Whether a run's name and key say its ε: an EBP method's, other than
    EPSILON_UNMARKED (an unknown method's too: it is not taken for a plain run)."""
    spec = METHODS.get(method)
    return (spec is None or spec.energy_prioritised) and energy_epsilon != EPSILON_UNMARKED


def energy_epsilon(config: dict[str, Any]) -> float:
    """A config.yaml's `energy.epsilon`: absent (saved before it was), 1e-6, every run's then;
    null (written by hand), the default of its `task.env_version`."""
    energy = config.get("energy") or {}
    if "epsilon" not in energy:
        return EPSILON_V1
    if energy["epsilon"] is None:
        return default_energy_epsilon((config.get("task") or {}).get("env_version",
                                                                     ENV_VERSION_DEFAULT))
    return float(energy["epsilon"])


def method_key(method: str, schedule: str = "async", precision: str = "fp32",
               env_version: str = ENV_VERSION_DEFAULT, variant: str = "",
               torquescale: float = 1.0, energy_epsilon: float = EPSILON_UNMARKED, *,
               lag: PolicyLag = DEFAULT_LAG,
               share_rule: str = ClusterConfig.share_rule) -> str:
    """The method, then what differs from the defaults: `/lockstep` (or another program's
    schedule), `/bf16`, `/<variant>` (a caller's, `VariantOf`), `/lag=…` (asynchronous
    only), `/eps0.001`, `/share=<rule>`, and last the environment: `/v1`, or `/ts4` for v4
    with the gripper weld's torquescale 4 (`her-cs/lockstep/bf16/v1`)."""
    env = env_version if torquescale == 1.0 else f"ts{torquescale:g}"
    eps = f"eps{energy_epsilon:g}" if marks_epsilon(method, energy_epsilon) else ""
    lags = lag.component() if schedule == "async" and lag != DEFAULT_LAG else ""
    share = f"share={share_rule}" if share_rule != ClusterConfig.share_rule else ""
    parts = (v for v, default in ((schedule, "async"), (precision, "fp32"), (variant, ""),
                                  (lags, ""), (eps, ""), (share, ""),
                                  (env, ENV_VERSION_DEFAULT)) if v != default)
    return "/".join((method, *parts))


VariantOf = Callable[[dict[str, Any]], str]
"""A caller's own grouping of runs beyond their settings: the variant for a run's
config.yaml, "" for none. `hercs plot` has none: a user's runs are grouped by settings."""


def series_key(config: dict[str, Any], variant_of: VariantOf | None = None) -> str:
    """A run's key from its config.yaml (task.name, run.method present; KeyError if not)."""
    task, training = config["task"], config.get("training") or {}
    return method_key(config["run"]["method"], training.get("schedule", "async"),
                      (config.get("learner") or {}).get("precision", "fp32"),
                      task.get("env_version", ENV_VERSION_DEFAULT),
                      variant_of(config) if variant_of is not None else "",
                      float(task.get("weld_torquescale", 1.0)), energy_epsilon(config),
                      lag=policy_lag(config),
                      share_rule=(config.get("cluster") or {}).get("share_rule",
                                                                    ClusterConfig.share_rule))


def is_env_version(part: str) -> bool:
    return part in ("v1", ENV_VERSION_DEFAULT) or part.startswith("ts")


def _lag_words(part: str) -> str:
    """`lag=80,3,2,-1` → "lag 80/3/2/∞" (tolerance / prefetch / queue / bound)."""
    values = part.removeprefix("lag=").split(",")
    return "lag " + "/".join("∞" if v == "-1" else v for v in values)


def method_label(key: str, variant_notes: Mapping[str, str] | None = None) -> str:
    """`her-cs` → "HER-CS", `her-cs/lockstep` → "HER-CS lockstep", `her-ebp/eps0.001` →
    "HER-EBP ε 0.001", `her-cs/v1` → "HER-CS (v1)", `her-cs/lag=80,3,2,-1` → "HER-CS (lag
    80/3/2/∞)"; another program's schedule is left out (`whose` says it); a variant named in
    `variant_notes` is a note after the others: {"old": "before"} → "HER-CS (before)"."""
    notes_of = variant_notes or {}
    method, *parts = key.split("/")
    inline = (f"ε {v[3:]}" if v.startswith("eps") else
              f"share {v[6:]}" if v.startswith("share=") else v
              for v in parts if not is_env_version(v) and v not in notes_of
              and v not in OTHER_CODE and not v.startswith("lag="))
    label = " ".join((METHOD_LABELS.get(method, method), *inline))
    notes = [f"torquescale {v[2:]}" if v.startswith("ts") else v
             for v in parts if is_env_version(v)]
    notes += [_lag_words(v) for v in parts if v.startswith("lag=") and v not in notes_of]
    notes += [notes_of[v] for v in parts if notes_of.get(v)]  # "": no note
    return "".join((label, *(f" ({v})" for v in notes)))


def whose(key: str) -> str:
    """"ours", or whose runs another program's schedule in the key says they are."""
    return next((OTHER_CODE[v] for v in key.split("/")[1:] if v in OTHER_CODE), "ours")


def method_rank(key: str) -> tuple[int, str]:
    """The paper's order; a variant right after its method."""
    method = key.partition("/")[0]
    return (METHOD_ORDER.index(method) if method in METHOD_ORDER else len(METHOD_ORDER), key)


def setting(key: str) -> tuple[int, int, tuple[str, ...]]:
    """What a key changes from today's defaults, for the default choice: (how many settings,
    how many environment parts, which). A v4 EBP run's ε 1e-3 is today's default and its
    unmarked 1e-6 a change, so that `her-ebp/eps0.001` and `her-cs` rank alike."""
    method, *parts = key.split("/")
    env = [v for v in parts if is_env_version(v)]
    changed = [v for v in parts if not is_env_version(v)]
    spec = METHODS.get(method)
    if spec is not None and spec.energy_prioritised and "v1" not in env:
        today = f"eps{default_energy_epsilon(ENV_VERSION_DEFAULT):g}"
        changed = ([v for v in changed if v != today]
                   + ([] if today in parts else [f"eps{EPSILON_UNMARKED:g}"]))
    return (len(changed), len(env), tuple(sorted(changed + env)))


@dataclass(frozen=True)
class SeriesChoice:
    """Which of our series a panel draws: `patterns` (`--series`, shell-style, matched
    against a key or its label, case-insensitive) draws those that match; `every`
    (`--all-series`) all; else those with the fewest settings changed, up to `limit`."""

    patterns: tuple[str, ...] = ()
    every: bool = False
    limit: int = MAX_SERIES

    def matches(self, key: str) -> bool:
        names = (key.casefold(), series_label(key).casefold())
        return any(fnmatch.fnmatchcase(n, p.casefold()) for p in self.patterns for n in names)

    def choose(self, keys: Iterable[str], cost: Callable[[str, list[str]], int]
               ) -> tuple[list[str], list[str]]:
        """(drawn, left out), each in the paper's order. By default the settings in
        `setting` order, each with its series of every method, until the next would pass
        `limit`; `cost(key, drawn so far)` is how many series drawing `key` adds (with
        `--reference`, the authors' curve of its method too, if not yet drawn)."""
        keys = sorted(set(keys), key=method_rank)
        if self.every or self.patterns:
            drawn = [k for k in keys if self.every or self.matches(k)]
        else:  # a setting's series of every method together, or none of them
            drawn, used = [], 0
            for _, unit in itertools.groupby(sorted(keys, key=lambda k: (setting(k),
                                                                          method_rank(k))),
                                             key=setting):
                members = list(unit)
                more = sum(cost(k, drawn + members[:i]) for i, k in enumerate(members))
                if used + more > self.limit:
                    break
                used += more
                drawn += members
        return (sorted(drawn, key=method_rank), [k for k in keys if k not in drawn])


DEFAULT_CHOICE = SeriesChoice()


def series_label(key: str) -> str:
    """The label, and whose the runs are where another program made them."""
    return method_label(key) + (f" ({whose(key)})" if whose(key) != "ours" else "")


def series_list(keys: Sequence[str]) -> str:
    return ", ".join(series_label(k) for k in keys)
