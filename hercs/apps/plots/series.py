"""What one series of `hercs plot` is: the runs that differ by their seed alone.

A series key is the method followed by every setting a run's config.yaml changes that makes it
another experiment (schedule, precision, a caller's variant, the policy-lag settings, EBP's ε,
the cluster share rule, the environment), "/"-joined; `method_label` says it in words and
`choose` picks the few series a panel draws (docs/DESIGN.md §6, "Figures").
"""

from __future__ import annotations

import fnmatch
import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hercs.apps.plots.numbers import power_of_ten
from hercs.config import TrainingConfig
from hercs.config.algorithm import EPSILON_V1, ClusterConfig, EnergyConfig, default_energy_epsilon
from hercs.config.deploy import ActorConfig, LearnerConfig
from hercs.config.replay import ReplayConfig
from hercs.config.unsaved import unsaved_default
from hercs.rl.methods import METHODS

ENV_VERSION_DEFAULT = "v4"
"""`task.env_version` of a run whose config.yaml has none (written before v1 existed)."""
EPSILON_UNMARKED = EPSILON_V1
"""EBP's ε that run names and keys leave unsaid on every simulator: v1's default, and that of
a saved config without `energy.epsilon` (`unsaved_default`). An EBP run with another (v4's
default 1e-3 included) is marked `eps…`; ε does nothing to HER and HER-CS, whose runs are
never marked."""
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


def policy_lag(config: dict[str, Any]) -> PolicyLag:
    """An asynchronous run's lag settings. A field that a saved config.yaml (one whose
    `replay` holds `rate_tolerance_updates`, as every run's does) lacks is the value it ran
    with (the field's `unsaved_default`); a config written by hand, without it, has the
    defaults."""
    saved = "rate_tolerance_updates" in (config.get("replay") or {})

    def read(section: str, kind: type, key: str, default: float) -> float:
        values = config.get(section) or {}
        return float(values.get(key, unsaved_default(kind, key) if saved else default))

    return PolicyLag(read("replay", ReplayConfig, "rate_tolerance_updates", DEFAULT_LAG.tolerance),
                     int(read("learner", LearnerConfig, "prefetch_depth", DEFAULT_LAG.prefetch)),
                     int(read("actor", ActorConfig, "insert_queue", DEFAULT_LAG.queue)),
                     int(read("training", TrainingConfig, "max_policy_lag", DEFAULT_LAG.bound)))


def marks_epsilon(method: str, energy_epsilon: float) -> bool:
    """Whether a run's name and key say its ε: an EBP method's, other than
    EPSILON_UNMARKED (an unknown method's too: it is not taken for a plain run)."""
    spec = METHODS.get(method)
    return (spec is None or spec.needs.energy) and energy_epsilon != EPSILON_UNMARKED


def energy_epsilon(config: dict[str, Any]) -> float:
    """A config.yaml's `energy.epsilon`: absent (saved before it was), what such runs ran
    with (`unsaved_default`); null (written by hand), the default of its `task.env_version`."""
    energy = config.get("energy") or {}
    if "epsilon" not in energy:
        return float(unsaved_default(EnergyConfig, "epsilon"))
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


SCHEDULE_WORDS: dict[str, str] = {"lockstep": "lockstep (as the authors' code)"}
"""A schedule other than the asynchronous default, in words (docs/results/README.md's
glossary); another program's schedule is said by `whose` instead."""
PRECISION_WORDS: dict[str, str] = {"bf16": "bf16 learner", "tf32": "TF32 learner"}


def lag_words(lag: PolicyLag) -> list[str]:
    """What an asynchronous run's policy-lag settings change from hercs' defaults, in words:
    `lag=80,3,2,-1` → ["no lag bound", "prefetch 3", "actor queue 2", "rate tolerance 80"]."""
    words = []
    if lag.bound != DEFAULT_LAG.bound:
        words.append("no lag bound" if lag.bound < 0 else f"lag bound {lag.bound}")
    if lag.prefetch != DEFAULT_LAG.prefetch:
        words.append(f"prefetch {lag.prefetch}")
    if lag.queue != DEFAULT_LAG.queue:
        words.append(f"actor queue {lag.queue}")
    if lag.tolerance != DEFAULT_LAG.tolerance:
        words.append(f"rate tolerance {lag.tolerance:g}")
    return words


def _lag_of(part: str) -> PolicyLag:
    tolerance, prefetch, queue, bound = part.removeprefix("lag=").split(",")
    return PolicyLag(float(tolerance), int(prefetch), int(queue), int(bound))


def _epsilon_words(value: float) -> str:
    return f"ε = {power_of_ten(value)}"


def unsaid_epsilon(key: str) -> float | None:
    """The ε of an energy-prioritised series whose key leaves it unsaid (EPSILON_UNMARKED) on
    a simulator whose default today is another (v4: 1e-3): a label says it, since the runs'
    name does not. None where the key says ε, or it is its simulator's default."""
    method, *parts = key.split("/")
    spec = METHODS.get(method)
    if spec is None or not spec.needs.energy or any(v.startswith("eps") for v in parts):
        return None
    env = "v1" if "v1" in parts else ENV_VERSION_DEFAULT
    return EPSILON_UNMARKED if default_energy_epsilon(env) != EPSILON_UNMARKED else None


def part_words(part: str) -> str:
    """One part of a series key in words ("" for another program's schedule: `whose`)."""
    if part in OTHER_CODE:
        return ""
    if part in SCHEDULE_WORDS:
        return SCHEDULE_WORDS[part]
    if part in PRECISION_WORDS:
        return PRECISION_WORDS[part]
    if part.startswith("lag="):
        return ", ".join(lag_words(_lag_of(part)))
    if part.startswith("eps"):
        return _epsilon_words(float(part[3:]))
    if part.startswith("share="):
        return f"{part[6:]} share rule"
    if part == "v1":
        return "authors' simulator (v1)"
    if part.startswith("ts"):
        return f"weld torquescale {part[2:]}"
    return part  # a caller's variant: its own name


def method_label(key: str, variant_notes: Mapping[str, str] | None = None, *,
                 ours: bool = False) -> str:
    """The method, then what the series changes from hercs' defaults in words, each after a
    comma: `her-cs` → "HER-CS", `her-cs/lockstep/v1` → "HER-CS, lockstep (as the authors'
    code), authors' simulator (v1)", `her-ebp/eps0.001` → "HER-EBP, ε = 10⁻³",
    `her-cs/lag=80,3,2,-1` → "HER-CS, no lag bound, prefetch 3, actor queue 2, rate
    tolerance 80". With `ours` (runs of ours, not a method's name) an ε the key leaves unsaid
    is said too (`unsaid_epsilon`): a v4 `her-ebp` → "HER-EBP, ε = 10⁻⁶". A part named in
    `variant_notes` is said by its note instead: {"old": "before"} → "HER-CS, before"."""
    notes_of = variant_notes or {}
    method, *parts = key.split("/")
    env = [v for v in parts if is_env_version(v)]
    words = [notes_of[v] if v in notes_of else part_words(v)
             for v in parts if not is_env_version(v)]
    unsaid = unsaid_epsilon(key) if ours else None
    if unsaid is not None:
        words.append(_epsilon_words(unsaid))
    words += [notes_of[v] if v in notes_of else part_words(v) for v in env]
    label = METHODS[method].label if method in METHODS else method
    return ", ".join((label, *(w for w in words if w)))


def whose(key: str) -> str:
    """"ours", or whose runs another program's schedule in the key says they are."""
    return next((OTHER_CODE[v] for v in key.split("/")[1:] if v in OTHER_CODE), "ours")


def method_rank(key: str) -> tuple[int, str]:
    """The methods table's order (the paper's); a variant right after its method."""
    order = list(METHODS)
    method = key.partition("/")[0]
    return (order.index(method) if method in order else len(order), key)


def changes(key: str) -> tuple[list[str], list[str]]:
    """What a key changes from today's defaults: (its settings' parts, its environment's).
    A v4 EBP run's ε 1e-3 is today's default and its unmarked 1e-6 a change (`eps1e-06`),
    so that `her-ebp/eps0.001` and `her-cs` change alike: nothing."""
    method, *parts = key.split("/")
    env = [v for v in parts if is_env_version(v)]
    changed = [v for v in parts if not is_env_version(v)]
    spec = METHODS.get(method)
    if spec is not None and spec.needs.energy and "v1" not in env:
        today = f"eps{default_energy_epsilon(ENV_VERSION_DEFAULT):g}"
        changed = ([v for v in changed if v != today]
                   + ([] if today in parts else [f"eps{EPSILON_UNMARKED:g}"]))
    return changed, env


def setting(key: str) -> tuple[int, int, tuple[str, ...]]:
    """What a key changes from today's defaults, for the default choice (`changes`): (how
    many settings, how many environment parts, which)."""
    changed, env = changes(key)
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
    """The label of a series of runs (`method_label(ours=True)`), and whose the runs are
    where another program made them ("…, authors' code")."""
    return method_label(key, ours=True) + (f", {whose(key)}" if whose(key) != "ours" else "")


def series_list(keys: Sequence[str]) -> str:
    """Labels in a sentence: ";" between them, since a label has commas of its own."""
    return "; ".join(series_label(k) for k in keys)
