"""The upper bound of every numeric field of the config tree, each with where it comes from.

A field's lower bound is its section's business (`__post_init__`); most upper bounds are not:
how large a buffer may be depends on the task's sizes and the machine, how wide a network on
the wire's message limit. Each bound here is one rule, registered for its field in `BOUNDS`
(any machine) or `MACHINE_BOUNDS` (this machine's memory and CPUs), whose docstring derives it
and which returns the bound with what a larger value would do (`fixed` registers a bound that
depends on nothing else, `held_in_memory` the two of a count of things held in memory). The
numbers they share with the code that meets them are hercs.config.limits'; the sizes a config
makes, and what this machine holds, hercs.config.sizes'. Every `HercsConfig`
runs `check_bounds`; `check_machine` runs where a command builds the config it will run here
(`hercs.config.apply_overrides`, which every `hercs` command's config passes through), not
where a config describes a run held elsewhere (a run folder's config.yaml read by `hercs
view`, a checkpoint's, the config a remote actor fetches from its replay). A refusal names the
field, the value, the bound and why: `replay.buffer_transitions: got 1000000000, must be <=
172603049 here: 136 GiB of storage (7.2 KiB per episode of 50 steps) against this machine's
23.5 GiB of memory`. Where several fields share a bound, the one furthest from its default
is named.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from hercs.config.limits import (
    ACTOR_PROCESS_BYTES,
    ADDRESS_SPACE_BYTES,
    ENV_STEP_S,
    EXACT_COUNT,
    INSERT_WORKERS_PER_CPU,
    MAX_BACKOFF_S,
    MAX_BATCH_SIZE,
    MAX_ENVS_PER_PROCESS,
    MAX_MINIBATCHES_PER_REQUEST,
    MAX_ROWS_PER_REQUEST,
    MAX_STALL_S,
    MAX_WAIT_S,
    PID_MAX_LIMIT,
    PROTOBUF_MAX_BYTES,
    STARTUP_S,
    UINT32_MAX,
    ZENOH_MAX_SESSIONS,
)
from hercs.config.sizes import (
    FLOAT32_BYTES,
    MESSAGE_OVERHEAD_BYTES,
    Machine,
    approx,
    batch_message_bytes,
    episode_message_bytes,
    largest,
    learner_parameter_bytes,
    size_text,
    stored_episode_bytes,
    this_machine,
    weights_message_bytes,
)
from hercs.errors import ConfigError
from hercs.proto.schema import MAX_BATCH_BYTES

if TYPE_CHECKING:
    from hercs.config import HercsConfig
    from hercs.rl.task_spec import TaskSpec


@dataclass(frozen=True)
class Limit:
    """A field's bound for one config: the largest value it may take, and why (what the
    config's own value would do)."""

    most: float
    why: str


Rule = Callable[["HercsConfig", "TaskSpec"], Limit]
MachineRule = Callable[["HercsConfig", "TaskSpec", Machine], Limit]
BOUNDS: dict[str, Rule] = {}
"""The bound of each numeric field, by its dotted name, on any machine."""
MACHINE_BOUNDS: dict[str, MachineRule] = {}
"""The bounds that depend on the machine a run starts on (its memory and CPUs)."""


def bound(field: str) -> Callable[[Rule], Rule]:
    def register(rule: Rule) -> Rule:
        BOUNDS[field] = rule
        return rule
    return register


def machine_bound(field: str) -> Callable[[MachineRule], MachineRule]:
    def register(rule: MachineRule) -> MachineRule:
        MACHINE_BOUNDS[field] = rule
        return rule
    return register


def fixed(field: str, most: float, why: str, derivation: str) -> None:
    """Register a bound that depends on nothing else (`derivation`: where it comes from)."""
    def rule(c: HercsConfig, spec: TaskSpec) -> Limit:
        return Limit(most, why)
    rule.__doc__ = derivation
    bound(field)(rule)


def _value(config: HercsConfig, field: str) -> float:
    section, _, name = field.partition(".")
    value: float = getattr(getattr(config, section), name)
    return value


def _number(value: float) -> str:
    """A value as the user wrote it; an integer of over 20 digits as its size."""
    if isinstance(value, int):
        digits = str(value)
        return digits if len(digits) <= 20 else f"{approx(value)} (a {len(digits)}-digit integer)"
    return str(int(value)) if value.is_integer() and abs(value) < EXACT_COUNT else f"{value:g}"


def _refuse(config: HercsConfig, spec: TaskSpec, rules: dict[str, Callable[..., Limit]],
            *extra: object, here: str = "") -> None:
    """Raise ConfigError for a field past its bound. Where several are (a bound shared by
    fields, as the network's width and depth), it names the one furthest from its default:
    the one the user changed. A field whose bound is below 1 owes it to another field, and is
    named only if no other field is past its bound."""
    past: list[tuple[bool, float, str, float, Limit]] = []
    for field, rule in rules.items():
        value = _value(config, field)
        if value is None:  # energy.epsilon unset: the simulator's own
            continue
        limit = rule(config, spec, *extra)
        if value > limit.most:
            past.append((limit.most >= 1, _from_default(config, field), field, value, limit))
    if past:
        _, _, field, value, limit = max(past, key=lambda item: (item[0], item[1]))
        _raise(field, value, limit, here)


def _from_default(config: HercsConfig, field: str) -> float:
    """How many times its default `field` is (infinite for a default of 0)."""
    section, _, name = field.partition(".")
    (default,) = [f.default for f in dataclasses.fields(getattr(config, section))
                  if f.name == name]
    value = _value(config, field)
    if not isinstance(default, int | float) or default <= 0:
        return math.inf
    try:
        return float(value) / default
    except OverflowError:
        return math.inf


def _raise(field: str, value: float, limit: Limit, here: str) -> None:
    must = (f"must be <= {_number(limit.most)}{here}" if limit.most >= 1
            else f"no value of it fits{here}")
    raise ConfigError(f"{field}: got {_number(value)}, {must}: {limit.why}")


def check_bounds(config: HercsConfig) -> None:
    """Every field of `config` within its bound on any machine (`BOUNDS`)."""
    _refuse(config, config.task.spec, BOUNDS)


def check_machine(config: HercsConfig, machine: Machine | None = None) -> None:
    """Every field of `config` within what `machine` (this one by default) can hold."""
    _refuse(config, config.task.spec, MACHINE_BOUNDS, machine or this_machine(), here=" here")


# run and task ----------------------------------------------------------------------------------


fixed("run.seed", UINT32_MAX,
      "the reference's seeds are numpy's 32-bit seeds",
      "2^32 − 1: the reference seeds numpy's global generator with the root seed "
      "(`np.random.seed`, 0 ≤ seed < 2^32) [HER-py], so that is the range of seeds runs "
      "comparable with the paper's can have; a run's name carries it (`-s<seed>`).")


fixed("task.weld_torquescale", 100.0,
      "25x the 4 that matches MuJoCo 2.1's weld (docs/results/env_diff.md)",
      "100: 25× the 4 that makes v4's gripper as stiff against tilting as v1's "
      "(docs/results/env_diff.md); the weld's rotational rows would outweigh its positional ones "
      "far beyond any MuJoCo version's.")


@bound("task.episode_steps")
def _episode_steps(c: HercsConfig, spec: TaskSpec) -> Limit:
    """One episode must fit one `Episode` message within `replay.max_message_bytes`: the
    replay refuses a larger insert as oversized, every time. 0 (the task's own horizon)
    passes: `replay.max_message_bytes` is held to one episode of it (HercsConfig)."""
    limit = c.replay.max_message_bytes
    most = largest(lambda t: episode_message_bytes(spec, t) <= limit)
    size = episode_message_bytes(spec)
    return Limit(most, f"one episode of {spec.episode_steps} steps is a {size_text(size)} "
                       f"Episode message, and the replay refuses any over "
                       f"replay.max_message_bytes ({size_text(limit)})")


# ddpg -----------------------------------------------------------------------------------------


def _network_limit(c: HercsConfig, field: str, size_of: Callable[[int, int], int],
                   limit: int) -> Limit:
    """The largest value of `field` (hidden_size or hidden_layers, the other held) for which
    `size_of(hidden_size, hidden_layers)` stays within `limit`; why names what it is now."""
    d = c.ddpg

    def fits(n: int) -> bool:
        shape = (n, d.hidden_layers) if field == "hidden_size" else (d.hidden_size, n)
        return size_of(*shape) <= limit
    return Limit(largest(fits), f"{_number(d.hidden_layers)} layers of "
                                f"{_number(d.hidden_size)} units make "
                                f"{size_text(size_of(d.hidden_size, d.hidden_layers))}")


def _weights_limit(c: HercsConfig, spec: TaskSpec, field: str) -> Limit:
    limit = c.replay.max_message_bytes
    shape = _network_limit(c, field, lambda h, n: weights_message_bytes(spec, h, n), limit)
    return Limit(shape.most, f"the actor's weights ({shape.why}) are one Weights message, "
                             f"and every actor refuses one over replay.max_message_bytes "
                             f"({size_text(limit)})")


@bound("ddpg.hidden_size")
def _hidden_size(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The actor's weights must fit one `Weights` message within `replay.max_message_bytes`,
    which every actor and the evaluator parse with that limit: a larger one is refused and
    the run never acts with its learner's weights. ~1,000 units at 3 layers with the default
    8 MiB."""
    return _weights_limit(c, spec, "hidden_size")


@bound("ddpg.hidden_layers")
def _hidden_layers(c: HercsConfig, spec: TaskSpec) -> Limit:
    """As `ddpg.hidden_size`: the actor's weights fit one `Weights` message (32 layers of
    256 with the default 8 MiB)."""
    return _weights_limit(c, spec, "hidden_layers")


@bound("ddpg.batch_size")
def _batch_size(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The replay serves at most `MAX_BATCH_SIZE` rows per minibatch and
    `MAX_ROWS_PER_REQUEST` per request (`training.minibatches_per_cycle` minibatches), and
    the learner reads a Batch of at most `MAX_BATCH_BYTES`: past any of them every request
    is refused and the learner asks for ever."""
    m = c.training.minibatches_per_cycle
    by_bytes = largest(lambda b: batch_message_bytes(spec, b, m) <= MAX_BATCH_BYTES)
    most = min(MAX_BATCH_SIZE, MAX_ROWS_PER_REQUEST // m, by_bytes)
    return Limit(most, f"the replay serves minibatches of at most {MAX_BATCH_SIZE} rows, "
                       f"{MAX_ROWS_PER_REQUEST} rows per request "
                       f"(training.minibatches_per_cycle {m} minibatches) and Batch replies "
                       f"up to {size_text(MAX_BATCH_BYTES)}; it would refuse every request")


fixed("ddpg.lr_actor", 1.0,
      "Adam moves each weight by about lr per step",
      "1: Adam moves each weight by about lr per step; past 1 it leaves any sensible scale "
      "(checked with the lower bound in DDPGConfig).")


fixed("ddpg.lr_critic", 1.0,
      "Adam moves each weight by about lr per step",
      "As `ddpg.lr_actor`.")


fixed("ddpg.gamma", math.nextafter(1.0, 0.0),
      "the return clip -1/(1-gamma) needs gamma < 1",
      "Below 1 (DDPGConfig): the clipped return −1/(1−γ) needs γ < 1.")


fixed("ddpg.polyak", 1.0,
      "it weighs an average",
      "1: θ' ← polyak·θ' + (1−polyak)·θ is an average (DDPGConfig).")


fixed("ddpg.random_eps", 1.0,
      "a probability",
      "1: a probability (DDPGConfig).")


@bound("ddpg.action_l2")
def _action_l2(c: HercsConfig, spec: TaskSpec) -> Limit:
    """1/(1−γ): the critic's values lie in [−1/(1−γ), 0] (rewards −1 or 0), so the actor's
    loss −Q is at most 1/(1−γ), and the penalty action_l2·mean((a/max)²) at most action_l2:
    past 1/(1−γ) (50 at the paper's γ) the penalty outweighs every return the critic can
    value and the actor learns only to keep still."""
    most = 1.0 / (1.0 - c.ddpg.gamma)
    return Limit(most, f"the penalty would outweigh every return the critic can value "
                       f"(1/(1-ddpg.gamma) = {most:g})")


fixed("ddpg.noise_eps", 10.0,
      "at noise 10x the action range over 92% of exploring actions are clipped to +-max_action "
      "whatever the policy says",
      "10: exploring actions are clip(μ + noise_eps·max_action·N(0, 1), ±max_action); at 10 "
      "standard deviations of ten times the action range's half-width, 92 % of them are clipped "
      "to ±max_action whatever μ says, and the policy no longer steers exploration.")


FLOAT32_MAX = 3.4028234663852886e38
FLOAT64_MAX = 1.7976931348623157e308


fixed("ddpg.clip_obs", FLOAT32_MAX,
      "observations are float32: a larger clip clips nothing",
      "float32's largest value: observations travel and are stored as float32, so a clip past it "
      "clips nothing.")


@bound("ddpg.norm_clip")
def _norm_clip(c: HercsConfig, spec: TaskSpec) -> Limit:
    """2·clip_obs/norm_eps: a clipped observation is within 2·clip_obs of the mean and the
    standard deviation is at least norm_eps, so no normalised input exceeds it and a larger
    clip means nothing."""
    most = 2 * c.ddpg.clip_obs / c.ddpg.norm_eps
    return Limit(most, f"no normalised input exceeds 2*ddpg.clip_obs/ddpg.norm_eps = {most:g}")


@bound("ddpg.norm_eps")
def _norm_eps(c: HercsConfig, spec: TaskSpec) -> Limit:
    """clip_obs: values clipped to ±clip_obs have a standard deviation of at most clip_obs,
    so a larger floor replaces every standard deviation and the normaliser only centres."""
    return Limit(c.ddpg.clip_obs, "a floor above ddpg.clip_obs (the largest standard "
                                  "deviation clipped values have) replaces every one")


@bound("her.replay_k")
def _replay_k(c: HercsConfig, spec: TaskSpec) -> Limit:
    """batch_size − 1: of a minibatch's B transitions B/(k+1) keep the goal they were acted
    for, on average; past B − 1 fewer than one does, and the critic never sees the episode's
    own goal it is evaluated on."""
    batch = _number(c.ddpg.batch_size)
    return Limit(c.ddpg.batch_size - 1,
                 f"fewer than one of a minibatch's {batch} transitions would keep its goal")


# cluster --------------------------------------------------------------------------------------


@bound("cluster.k")
def _k(c: HercsConfig, spec: TaskSpec) -> Limit:
    """With clusters, batch_size: each of the k clusters gets ⌊B/k⌋ draws, none past B, and
    the draw is HER's uniform one. Always at most fgb_size (ClusterConfig): k-means of fewer
    goals than clusters."""
    if not c.run.uses_clusters:
        return Limit(c.cluster.fgb_size, "k-means needs a goal per cluster")
    most = min(c.ddpg.batch_size, c.cluster.fgb_size)
    return Limit(most, f"each cluster's share of a minibatch of {_number(c.ddpg.batch_size)} "
                       f"would be 0 (or k-means would have fewer goals than clusters)")


@bound("cluster.fgb_size")
def _fgb_size(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The failed goals travel whole to a restarted clusterer (`ClustererState`, (n, goal_dim)
    float32) within `replay.max_message_bytes`."""
    limit = c.replay.max_message_bytes
    most = (limit - MESSAGE_OVERHEAD_BYTES) // (FLOAT32_BYTES * spec.goal_dim)
    return Limit(most, f"a restarted clusterer receives the failed goals in one message, and "
                       f"the replay.max_message_bytes limit ({size_text(limit)}) holds "
                       f"{most} goals")


@bound("cluster.small_cluster_repeat")
def _small_cluster_repeat(c: HercsConfig, spec: TaskSpec) -> Limit:
    """batch_size: a cluster is small when it has fewer than share/repeat members, with a
    share of at most B, so past B no cluster is ever small. Without clusters, the largest
    batch (`MAX_BATCH_SIZE`)."""
    most = c.ddpg.batch_size if c.run.uses_clusters else MAX_BATCH_SIZE
    return Limit(most, "no cluster would ever count as small (a share is at most "
                       "ddpg.batch_size)")


fixed("cluster.kmeans_n_init", 100,
      "a refit would take longer than the failures that call for it",
      "100: each restart of k-means on the paper's 150 failed goals took ~40 ms on the "
      "development machine, so 100 make a ~4 s refit against the ~7.5 s one FetchPush actor needs "
      "to fail 150 episodes: past it the models fall behind the goals they are fitted to.")


# energy ---------------------------------------------------------------------------------------

ENERGY_SCALE_RANGE = 1e6
"""How far an energy scale may move from the reference's value (m = 1, g = 9.81, I = 1, the
weights 1, Δt = 0.04 [EBP]). Each only sets how large a movement reaches the per-transition
clip (0.5): at a million times the kinetic term ½·m·(Δx/Δt)², a tenth of a millimetre per
step already does (½·10⁶·(10⁻⁴/0.04)² = 3.1), so every episode in which anything trembles
has the most energy and EBP draws uniformly; Δt a thousand times longer makes every
energy a millionth, below ε."""


def _energy_scale(reference: float, name: str) -> Rule:
    def rule(c: HercsConfig, spec: TaskSpec) -> Limit:
        most = reference * ENERGY_SCALE_RANGE
        return Limit(most, f"a million times the reference's {reference:g}: the smallest "
                           f"tremble would reach the energy clip and EBP would draw uniformly")
    rule.__doc__ = f"A million times the reference's {name} (`ENERGY_SCALE_RANGE`)."
    return rule


for _field, _reference in (("mass", 1.0), ("gravity", 9.81), ("inertia", 1.0),
                           ("w_potential", 1.0), ("w_kinetic", 1.0), ("w_rotational", 1.0)):
    bound(f"energy.{_field}")(_energy_scale(_reference, _field))


fixed("energy.delta_t", 40.0,
      "every kinetic energy would be a millionth of the reference's",
      "40 s, a thousand times the reference's 0.04: the kinetic terms fall with Δt², so every "
      "energy would be a millionth of the reference's (`ENERGY_SCALE_RANGE`).")


def _max_energy_term(c: HercsConfig, spec: TaskSpec) -> float:
    """The largest E^exponent an episode's energy gives: E ≤ T·clip_energy (float64)."""
    try:
        return float((spec.episode_steps * c.energy.clip_energy) ** c.energy.exponent)
    except OverflowError:
        return math.inf


@bound("energy.clip_energy")
def _clip_energy(c: HercsConfig, spec: TaskSpec) -> Limit:
    """An episode's energy is at most T·clip_energy and is raised to 1/(temperature + 0.01):
    that must stay a finite float64, or the draw's probabilities become inf/inf = NaN."""
    try:
        most = math.pow(FLOAT64_MAX, 1.0 / c.energy.exponent) / spec.episode_steps
    except OverflowError:  # a tiny exponent: no clip can overflow
        most = FLOAT64_MAX
    return Limit(most, f"(T x clip_energy)^{c.energy.exponent:g} would overflow float64 and "
                       f"the sampling probabilities would be NaN")


@bound("energy.epsilon")
def _epsilon(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The largest energy term an episode can have, (T·clip_energy)^exponent: a larger ε
    outweighs every episode's energy and the draw is within a factor 2 of uniform."""
    most = _max_energy_term(c, spec)
    return Limit(most, f"it would outweigh the largest energy an episode can have "
                       f"((T x clip_energy)^exponent = {most:g})")


fixed("energy.temperature", 1000.0,
      "energies raised to under 1/1000 all weigh the same",
      "1000: the energies are raised to 1/(temperature + 0.01), below a thousandth there, and the "
      "largest and smallest trajectory energies of a Fetch task (25 and ε) then differ in p by "
      "about 1 %: EBP would draw uniformly.")


# training -------------------------------------------------------------------------------------


def _per_epoch(c: HercsConfig, spec: TaskSpec) -> int:
    t = c.training
    return t.cycles_per_epoch * max(t.episodes_per_cycle * spec.episode_steps,
                                    t.minibatches_per_cycle, 1)


def _count_limit(c: HercsConfig, spec: TaskSpec, others: int) -> Limit:
    total = c.training.epochs * _per_epoch(c, spec)
    return Limit(EXACT_COUNT // max(others, 1),
                 f"the run would count {approx(total)} env steps or updates, and metrics.csv "
                 f"records counts as doubles, exact to 2^53")


@bound("training.epochs")
def _epochs(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The run's counts (env steps, updates, weights versions) must be exact where they are
    recorded (`EXACT_COUNT`): epochs × the most of them an epoch adds."""
    return _count_limit(c, spec, _per_epoch(c, spec))


@bound("training.cycles_per_epoch")
def _cycles(c: HercsConfig, spec: TaskSpec) -> Limit:
    """As `training.epochs`."""
    t = c.training
    return _count_limit(c, spec, t.epochs * max(t.episodes_per_cycle * spec.episode_steps,
                                                t.minibatches_per_cycle, 1))


@bound("training.episodes_per_cycle")
def _episodes_per_cycle(c: HercsConfig, spec: TaskSpec) -> Limit:
    """As `training.epochs` (env steps: epochs × cycles × episodes × T)."""
    t = c.training
    return _count_limit(c, spec, t.epochs * t.cycles_per_epoch * spec.episode_steps)


@bound("training.minibatches_per_cycle")
def _minibatches(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The replay serves at most `MAX_MINIBATCHES_PER_REQUEST` minibatches per request (the
    learner asks for a cycle's): past it every request is refused. And the run's updates are
    counted exactly (`EXACT_COUNT`)."""
    t = c.training
    most = min(MAX_MINIBATCHES_PER_REQUEST, EXACT_COUNT // (t.epochs * t.cycles_per_epoch))
    return Limit(most, f"the replay serves at most {MAX_MINIBATCHES_PER_REQUEST} minibatches "
                       f"per request and would refuse every one")


@bound("training.eval_episodes")
def _eval_episodes(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The last epoch's evaluation must be able to end within `training.eval_wait_s`, or the
    learner gives the run up (exit 1): at the reference machine's `ENV_STEP_S` per step,
    eval_wait_s / (T·ENV_STEP_S) episodes (12,000 with the defaults). Also a proto uint32
    (`EvalResult.episodes`)."""
    steps = spec.episode_steps
    most = min(UINT32_MAX, int(c.training.eval_wait_s / (steps * ENV_STEP_S)))
    total = approx(c.training.eval_episodes * steps)
    return Limit(most, f"one evaluation of {_number(c.training.eval_episodes)} episodes of "
                       f"{steps} steps is {total} env steps, at {ENV_STEP_S * 1000:g} ms a step "
                       f"longer than training.eval_wait_s ({c.training.eval_wait_s:g} s), which "
                       f"the learner waits for the last one before it ends the run (exit 1)")


def _wait(what: str) -> Rule:
    def rule(c: HercsConfig, spec: TaskSpec) -> Limit:
        return Limit(MAX_WAIT_S, f"a {what} longer than a day guards nothing: the stall "
                                 f"watchdog ends a run that stood still that long")
    rule.__doc__ = f"`MAX_WAIT_S` (a day): a {what}."
    return rule


for _field, _what in (("training.eval_resend_s", "resend period"),
                      ("training.eval_wait_s", "wait"),
                      ("replay.sample_timeout_s", "timeout"),
                      ("actor.insert_timeout_s", "timeout"),
                      ("transport.wait_s", "wait"),
                      ("transport.rediscover_s", "wait"),
                      ("transport.cut_off_s", "wait"),
                      ("tracking.finish_wait_s", "wait")):
    bound(_field)(_wait(_what))


fixed("training.checkpoint_every", EXACT_COUNT,
      "past every epoch number a run records exactly",
      "`EXACT_COUNT`: an epoch number metrics.csv records exactly (0: none).")


fixed("training.max_policy_lag", EXACT_COUNT,
      "past every weights version a run records exactly (-1: no bound)",
      "`EXACT_COUNT`: a lag in cycles, compared with weights versions recorded as doubles (-1: no "
      "bound).")


# replay ---------------------------------------------------------------------------------------


def _storage(c: HercsConfig, spec: TaskSpec, transitions: int) -> int:
    clusters = c.cluster.k if c.run.uses_clusters else 0
    return (transitions // spec.episode_steps) * stored_episode_bytes(spec, clusters)


def _buffer_limit(c: HercsConfig, spec: TaskSpec, memory: int, against: str) -> Limit:
    clusters = c.cluster.k if c.run.uses_clusters else 0
    per_episode = stored_episode_bytes(spec, clusters)
    most = (memory // per_episode) * spec.episode_steps + spec.episode_steps - 1
    storage = _storage(c, spec, c.replay.buffer_transitions)
    return Limit(most, f"{size_text(storage)} of storage ({size_text(per_episode)} per episode "
                       f"of {spec.episode_steps} steps) against {against}")


@bound("replay.buffer_transitions")
def _buffer(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The replay's store (`stored_episode_bytes` per episode) must fit one process's address
    space (`ADDRESS_SPACE_BYTES`); `check_machine` holds it to the machine's memory too."""
    return _buffer_limit(c, spec, ADDRESS_SPACE_BYTES,
                         "a 64-bit process's address space (128 TiB)")


@machine_bound("replay.buffer_transitions")
def _buffer_here(c: HercsConfig, spec: TaskSpec, m: Machine) -> Limit:
    """The replay's store must fit this machine's memory: the audit's 10^15 transitions
    failed with ArrayMemoryError in a restart loop, and a store a little over the memory
    is killed once it fills."""
    return _buffer_limit(c, spec, m.memory_bytes,
                         f"this machine's {size_text(m.memory_bytes)} of memory")


@bound("replay.min_episodes_to_sample")
def _min_episodes(c: HercsConfig, spec: TaskSpec) -> Limit:
    """The rate limiter's centre ρ·N_min is a float: exact to `EXACT_COUNT`."""
    most = int(EXACT_COUNT / max(c.training.updates_per_episode, 1.0))
    return Limit(most, "the rate limiter's count would not be exact (2^53)")


fixed("replay.rate_tolerance_updates", EXACT_COUNT,
      "the rate limiter's count would not be exact (2^53)",
      "`EXACT_COUNT`: the limiter's surplus is a float count of minibatches.")


fixed("replay.max_message_bytes", PROTOBUF_MAX_BYTES,
      "protobuf encodes no message of 2 GiB or more",
      "`PROTOBUF_MAX_BYTES`: no larger message can be encoded.")


fixed("replay.insert_workers", PID_MAX_LIMIT,
      "Linux runs no more tasks",
      "`PID_MAX_LIMIT` on any machine; `check_machine` holds it to the CPUs.")


@machine_bound("replay.insert_workers")
def _insert_workers_here(c: HercsConfig, spec: TaskSpec, m: Machine) -> Limit:
    """`INSERT_WORKERS_PER_CPU` per CPU: the audit's 10^6 workers took 2.5 GB and the replay
    did not stop within 10 s of SIGTERM."""
    most = INSERT_WORKERS_PER_CPU * m.cpus
    return Limit(most, f"{INSERT_WORKERS_PER_CPU} per CPU of this machine's {m.cpus}: the "
                       "workers overlap fsyncs, and more only take memory and slow the stop")


def held_in_memory(field: str, what: str, each: Callable[[HercsConfig, TaskSpec], int],
                   why: str) -> None:
    """Register the two bounds of a count of things each held in memory (`each` bytes): within
    a 64-bit process's address space on any machine, within this machine's memory in
    `check_machine`; `why` says what holds them."""
    def rule(c: HercsConfig, spec: TaskSpec, memory: int, against: str) -> Limit:
        count, size = _value(c, field), each(c, spec)
        return Limit(memory // max(size, 1),
                     f"{_number(count)} {what} of {size_text(size)} each would hold "
                     f"{size_text(count * size)} against {against}")

    def anywhere(c: HercsConfig, spec: TaskSpec) -> Limit:
        return rule(c, spec, ADDRESS_SPACE_BYTES, "a process's address space (128 TiB)")

    def here(c: HercsConfig, spec: TaskSpec, m: Machine) -> Limit:
        return rule(c, spec, m.memory_bytes,
                    f"this machine's {size_text(m.memory_bytes)} of memory")
    anywhere.__doc__ = f"{why}: within a process's address space (`ADDRESS_SPACE_BYTES`)."
    here.__doc__ = f"{why}: within this machine's memory."
    bound(field)(anywhere)
    machine_bound(field)(here)


held_in_memory("replay.waiting_inserts_per_actor", "waiting episodes",
               lambda c, spec: episode_message_bytes(spec),
               "Each insert the replay holds waiting holds its episode")
held_in_memory("actor.insert_queue", "waiting episodes per env",
               lambda c, spec: c.actor.envs_per_process * episode_message_bytes(spec),
               "Each episode waiting behind an env's insert is held by its actor")
held_in_memory("learner.prefetch_depth", "batches sampled ahead",
               lambda c, spec: batch_message_bytes(spec, c.ddpg.batch_size,
                                                   c.training.minibatches_per_cycle),
               "Each batch sampled ahead is held by the learner")


@machine_bound("actor.num_actors")
def _num_actors_here(c: HercsConfig, spec: TaskSpec, m: Machine) -> Limit:
    """`ACTOR_PROCESS_BYTES` per actor process within this machine's memory (`hercs up` starts
    them here)."""
    count = c.actor.num_actors
    return Limit(m.memory_bytes // ACTOR_PROCESS_BYTES,
                 f"{_number(count)} actor processes of at least "
                 f"{size_text(ACTOR_PROCESS_BYTES)} each would hold "
                 f"{size_text(count * ACTOR_PROCESS_BYTES)} against this machine's "
                 f"{size_text(m.memory_bytes)} of memory")


fixed("replay.log_max_bytes", 2**63 - 1,
      "no file system states a larger size (-1 keeps the whole log)",
      "2^63 − 1: a file size (`off_t`) is a signed 64-bit integer; -1 keeps the whole log.")


fixed("replay.log_segments_per_buffer", 1000,
      "each segment is a file that repeats the replay's state",
      "1000: each segment is a file that starts with the replay's state (normaliser statistics, "
      "failed goals, cluster model: ~4 KB on FetchPush); past 1000 the paper's buffer is cut into "
      "segments of 20 episodes that each repeat it, and resume scans over 1,500 files.")


# actor, learner, launch, view -----------------------------------------------------------------


fixed("actor.num_actors", ZENOH_MAX_SESSIONS - 6,
      f"the router accepts {ZENOH_MAX_SESSIONS} sessions and the run's other processes take six",
      "Each actor is a Zenoh session of the router, which takes `ZENOH_MAX_SESSIONS`, six of them "
      "the run's other processes; `check_machine` holds them to the memory too.")


fixed("actor.envs_per_process", MAX_ENVS_PER_PROCESS,
      "past a few hundred one process is slower than two",
      "`MAX_ENVS_PER_PROCESS` (checked with the lower bound in ActorConfig).")


def _network_here(c: HercsConfig, spec: TaskSpec, m: Machine, field: str) -> Limit:
    shape = _network_limit(c, field, lambda h, n: learner_parameter_bytes(spec, h, n),
                           m.memory_bytes)
    return Limit(shape.most, f"the learner's networks ({shape.why}, with their targets, "
                             f"gradients and Adam's moments) against this machine's "
                             f"{size_text(m.memory_bytes)} of memory")


@machine_bound("ddpg.hidden_size")
def _hidden_size_here(c: HercsConfig, spec: TaskSpec, m: Machine) -> Limit:
    """The learner's parameter memory (`learner_parameter_bytes`) within this machine's: the
    audit's 10^9 units made 52 GB allocations fail in a restart loop."""
    return _network_here(c, spec, m, "hidden_size")


@machine_bound("ddpg.hidden_layers")
def _hidden_layers_here(c: HercsConfig, spec: TaskSpec, m: Machine) -> Limit:
    """As `ddpg.hidden_size` (the audit's 10^26 layers grew memory without end)."""
    return _network_here(c, spec, m, "hidden_layers")


@bound("launch.max_restarts")
def _max_restarts(c: HercsConfig, spec: TaskSpec) -> Limit:
    """`MAX_STALL_S` / `MAX_BACKOFF_S` (2,880): a child that dies at every start is given up
    after its restarts, each at most `MAX_BACKOFF_S` apart; more would outlast the stall
    watchdog's longest bound."""
    most = int(MAX_STALL_S // MAX_BACKOFF_S)
    return Limit(most, f"restarts {MAX_BACKOFF_S:g} s apart would go on longer than a day")


fixed("launch.restart_backoff_s", MAX_BACKOFF_S,
      f"restart delays double up to {MAX_BACKOFF_S:g} s",
      "`MAX_BACKOFF_S`: the delays double up to it, so a first delay past it is it.")


@bound("launch.stall_factor")
def _stall_factor(c: HercsConfig, spec: TaskSpec) -> Limit:
    """`MAX_STALL_S` / `STARTUP_S` (1,440): the first epoch's bound is at least the factor
    times `STARTUP_S`, so past it the bound is the cap (`MAX_STALL_S`) whatever the config,
    no longer a factor of anything (0: never)."""
    most = MAX_STALL_S / STARTUP_S
    return Limit(most, f"the stall bound is capped at {MAX_STALL_S / 3600:g} h, which a "
                       f"larger factor reaches for every run")


fixed("view.episode_every", EXACT_COUNT,
      "past every episode id a run counts exactly",
      "`EXACT_COUNT`: a period over episode ids, which the run counts exactly (0: none).")
