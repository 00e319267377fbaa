from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Array(_message.Message):
    __slots__ = ("dtype", "shape", "data")
    DTYPE_FIELD_NUMBER: _ClassVar[int]
    SHAPE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    dtype: str
    shape: _containers.RepeatedScalarFieldContainer[int]
    data: bytes
    def __init__(self, dtype: _Optional[str] = ..., shape: _Optional[_Iterable[int]] = ..., data: _Optional[bytes] = ...) -> None: ...

class NamedArray(_message.Message):
    __slots__ = ("name", "array")
    NAME_FIELD_NUMBER: _ClassVar[int]
    ARRAY_FIELD_NUMBER: _ClassVar[int]
    name: str
    array: Array
    def __init__(self, name: _Optional[str] = ..., array: _Optional[_Union[Array, _Mapping]] = ...) -> None: ...

class NormalizerStats(_message.Message):
    __slots__ = ("sum", "sumsq", "count", "mean", "std")
    SUM_FIELD_NUMBER: _ClassVar[int]
    SUMSQ_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    MEAN_FIELD_NUMBER: _ClassVar[int]
    STD_FIELD_NUMBER: _ClassVar[int]
    sum: Array
    sumsq: Array
    count: float
    mean: Array
    std: Array
    def __init__(self, sum: _Optional[_Union[Array, _Mapping]] = ..., sumsq: _Optional[_Union[Array, _Mapping]] = ..., count: _Optional[float] = ..., mean: _Optional[_Union[Array, _Mapping]] = ..., std: _Optional[_Union[Array, _Mapping]] = ...) -> None: ...

class Episode(_message.Message):
    __slots__ = ("schema_version", "run", "actor_id", "seq", "task", "obs", "ag", "g", "actions", "success", "policy_version")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    RUN_FIELD_NUMBER: _ClassVar[int]
    ACTOR_ID_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    TASK_FIELD_NUMBER: _ClassVar[int]
    OBS_FIELD_NUMBER: _ClassVar[int]
    AG_FIELD_NUMBER: _ClassVar[int]
    G_FIELD_NUMBER: _ClassVar[int]
    ACTIONS_FIELD_NUMBER: _ClassVar[int]
    SUCCESS_FIELD_NUMBER: _ClassVar[int]
    POLICY_VERSION_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    run: str
    actor_id: str
    seq: int
    task: str
    obs: Array
    ag: Array
    g: Array
    actions: Array
    success: bool
    policy_version: int
    def __init__(self, schema_version: _Optional[int] = ..., run: _Optional[str] = ..., actor_id: _Optional[str] = ..., seq: _Optional[int] = ..., task: _Optional[str] = ..., obs: _Optional[_Union[Array, _Mapping]] = ..., ag: _Optional[_Union[Array, _Mapping]] = ..., g: _Optional[_Union[Array, _Mapping]] = ..., actions: _Optional[_Union[Array, _Mapping]] = ..., success: _Optional[bool] = ..., policy_version: _Optional[int] = ...) -> None: ...

class InsertAck(_message.Message):
    __slots__ = ("schema_version", "actor_id", "seq", "episode_id", "duplicate", "next_policy_version")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    ACTOR_ID_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    EPISODE_ID_FIELD_NUMBER: _ClassVar[int]
    DUPLICATE_FIELD_NUMBER: _ClassVar[int]
    NEXT_POLICY_VERSION_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    actor_id: str
    seq: int
    episode_id: int
    duplicate: bool
    next_policy_version: int
    def __init__(self, schema_version: _Optional[int] = ..., actor_id: _Optional[str] = ..., seq: _Optional[int] = ..., episode_id: _Optional[int] = ..., duplicate: _Optional[bool] = ..., next_policy_version: _Optional[int] = ...) -> None: ...

class EpisodeHeader(_message.Message):
    __slots__ = ("schema_version", "episode_id", "actor_id", "seq", "success", "final_achieved_goal", "desired_goal", "energy", "cluster", "policy_version")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    EPISODE_ID_FIELD_NUMBER: _ClassVar[int]
    ACTOR_ID_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    SUCCESS_FIELD_NUMBER: _ClassVar[int]
    FINAL_ACHIEVED_GOAL_FIELD_NUMBER: _ClassVar[int]
    DESIRED_GOAL_FIELD_NUMBER: _ClassVar[int]
    ENERGY_FIELD_NUMBER: _ClassVar[int]
    CLUSTER_FIELD_NUMBER: _ClassVar[int]
    POLICY_VERSION_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    episode_id: int
    actor_id: str
    seq: int
    success: bool
    final_achieved_goal: Array
    desired_goal: Array
    energy: float
    cluster: int
    policy_version: int
    def __init__(self, schema_version: _Optional[int] = ..., episode_id: _Optional[int] = ..., actor_id: _Optional[str] = ..., seq: _Optional[int] = ..., success: _Optional[bool] = ..., final_achieved_goal: _Optional[_Union[Array, _Mapping]] = ..., desired_goal: _Optional[_Union[Array, _Mapping]] = ..., energy: _Optional[float] = ..., cluster: _Optional[int] = ..., policy_version: _Optional[int] = ...) -> None: ...

class EpisodeRequest(_message.Message):
    __slots__ = ("schema_version", "episode_id")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    EPISODE_ID_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    episode_id: int
    def __init__(self, schema_version: _Optional[int] = ..., episode_id: _Optional[int] = ...) -> None: ...

class SampleRequest(_message.Message):
    __slots__ = ("schema_version", "run", "learner_id", "request_id", "num_minibatches", "batch_size", "weights_version", "samples_kept", "learner_incarnation")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    RUN_FIELD_NUMBER: _ClassVar[int]
    LEARNER_ID_FIELD_NUMBER: _ClassVar[int]
    REQUEST_ID_FIELD_NUMBER: _ClassVar[int]
    NUM_MINIBATCHES_FIELD_NUMBER: _ClassVar[int]
    BATCH_SIZE_FIELD_NUMBER: _ClassVar[int]
    WEIGHTS_VERSION_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_KEPT_FIELD_NUMBER: _ClassVar[int]
    LEARNER_INCARNATION_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    run: str
    learner_id: str
    request_id: int
    num_minibatches: int
    batch_size: int
    weights_version: int
    samples_kept: int
    learner_incarnation: str
    def __init__(self, schema_version: _Optional[int] = ..., run: _Optional[str] = ..., learner_id: _Optional[str] = ..., request_id: _Optional[int] = ..., num_minibatches: _Optional[int] = ..., batch_size: _Optional[int] = ..., weights_version: _Optional[int] = ..., samples_kept: _Optional[int] = ..., learner_incarnation: _Optional[str] = ...) -> None: ...

class Minibatch(_message.Message):
    __slots__ = ("o", "o2", "g", "u", "r")
    O_FIELD_NUMBER: _ClassVar[int]
    O2_FIELD_NUMBER: _ClassVar[int]
    G_FIELD_NUMBER: _ClassVar[int]
    U_FIELD_NUMBER: _ClassVar[int]
    R_FIELD_NUMBER: _ClassVar[int]
    o: Array
    o2: Array
    g: Array
    u: Array
    r: Array
    def __init__(self, o: _Optional[_Union[Array, _Mapping]] = ..., o2: _Optional[_Union[Array, _Mapping]] = ..., g: _Optional[_Union[Array, _Mapping]] = ..., u: _Optional[_Union[Array, _Mapping]] = ..., r: _Optional[_Union[Array, _Mapping]] = ...) -> None: ...

class Batch(_message.Message):
    __slots__ = ("schema_version", "request_id", "minibatches", "o_stats", "g_stats", "cluster_draws", "policy_lags", "sampled_moved", "sampled_transitions", "samples_served", "buffer_moved_share")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    REQUEST_ID_FIELD_NUMBER: _ClassVar[int]
    MINIBATCHES_FIELD_NUMBER: _ClassVar[int]
    O_STATS_FIELD_NUMBER: _ClassVar[int]
    G_STATS_FIELD_NUMBER: _ClassVar[int]
    CLUSTER_DRAWS_FIELD_NUMBER: _ClassVar[int]
    POLICY_LAGS_FIELD_NUMBER: _ClassVar[int]
    SAMPLED_MOVED_FIELD_NUMBER: _ClassVar[int]
    SAMPLED_TRANSITIONS_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_SERVED_FIELD_NUMBER: _ClassVar[int]
    BUFFER_MOVED_SHARE_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    request_id: int
    minibatches: _containers.RepeatedCompositeFieldContainer[Minibatch]
    o_stats: NormalizerStats
    g_stats: NormalizerStats
    cluster_draws: _containers.RepeatedScalarFieldContainer[int]
    policy_lags: _containers.RepeatedScalarFieldContainer[int]
    sampled_moved: int
    sampled_transitions: int
    samples_served: int
    buffer_moved_share: float
    def __init__(self, schema_version: _Optional[int] = ..., request_id: _Optional[int] = ..., minibatches: _Optional[_Iterable[_Union[Minibatch, _Mapping]]] = ..., o_stats: _Optional[_Union[NormalizerStats, _Mapping]] = ..., g_stats: _Optional[_Union[NormalizerStats, _Mapping]] = ..., cluster_draws: _Optional[_Iterable[int]] = ..., policy_lags: _Optional[_Iterable[int]] = ..., sampled_moved: _Optional[int] = ..., sampled_transitions: _Optional[int] = ..., samples_served: _Optional[int] = ..., buffer_moved_share: _Optional[float] = ...) -> None: ...

class ClusterModel(_message.Message):
    __slots__ = ("schema_version", "version", "centroids", "fitted_on", "failures_seen")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    CENTROIDS_FIELD_NUMBER: _ClassVar[int]
    FITTED_ON_FIELD_NUMBER: _ClassVar[int]
    FAILURES_SEEN_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    version: int
    centroids: Array
    fitted_on: int
    failures_seen: int
    def __init__(self, schema_version: _Optional[int] = ..., version: _Optional[int] = ..., centroids: _Optional[_Union[Array, _Mapping]] = ..., fitted_on: _Optional[int] = ..., failures_seen: _Optional[int] = ...) -> None: ...

class Weights(_message.Message):
    __slots__ = ("schema_version", "version", "actor_params", "o_stats", "g_stats", "epoch", "evaluate")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    ACTOR_PARAMS_FIELD_NUMBER: _ClassVar[int]
    O_STATS_FIELD_NUMBER: _ClassVar[int]
    G_STATS_FIELD_NUMBER: _ClassVar[int]
    EPOCH_FIELD_NUMBER: _ClassVar[int]
    EVALUATE_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    version: int
    actor_params: _containers.RepeatedCompositeFieldContainer[NamedArray]
    o_stats: NormalizerStats
    g_stats: NormalizerStats
    epoch: int
    evaluate: bool
    def __init__(self, schema_version: _Optional[int] = ..., version: _Optional[int] = ..., actor_params: _Optional[_Iterable[_Union[NamedArray, _Mapping]]] = ..., o_stats: _Optional[_Union[NormalizerStats, _Mapping]] = ..., g_stats: _Optional[_Union[NormalizerStats, _Mapping]] = ..., epoch: _Optional[int] = ..., evaluate: _Optional[bool] = ...) -> None: ...

class EvalResult(_message.Message):
    __slots__ = ("schema_version", "epoch", "weights_version", "episodes", "success_rate", "mean_final_distance")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    EPOCH_FIELD_NUMBER: _ClassVar[int]
    WEIGHTS_VERSION_FIELD_NUMBER: _ClassVar[int]
    EPISODES_FIELD_NUMBER: _ClassVar[int]
    SUCCESS_RATE_FIELD_NUMBER: _ClassVar[int]
    MEAN_FINAL_DISTANCE_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    epoch: int
    weights_version: int
    episodes: int
    success_rate: float
    mean_final_distance: float
    def __init__(self, schema_version: _Optional[int] = ..., epoch: _Optional[int] = ..., weights_version: _Optional[int] = ..., episodes: _Optional[int] = ..., success_rate: _Optional[float] = ..., mean_final_distance: _Optional[float] = ...) -> None: ...

class ReplayStatusRequest(_message.Message):
    __slots__ = ("schema_version", "samples")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    samples: int
    def __init__(self, schema_version: _Optional[int] = ..., samples: _Optional[int] = ...) -> None: ...

class ReplayStatus(_message.Message):
    __slots__ = ("schema_version", "size_episodes", "size_transitions", "inserts", "duplicates", "samples", "rate_limiter", "rejects", "cluster_sizes", "cluster_model_version", "env_steps", "policy_lag", "policy_lag_request", "buffer_moved_share", "inserts_waiting", "samples_waiting")
    class RejectsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    SIZE_EPISODES_FIELD_NUMBER: _ClassVar[int]
    SIZE_TRANSITIONS_FIELD_NUMBER: _ClassVar[int]
    INSERTS_FIELD_NUMBER: _ClassVar[int]
    DUPLICATES_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_FIELD_NUMBER: _ClassVar[int]
    RATE_LIMITER_FIELD_NUMBER: _ClassVar[int]
    REJECTS_FIELD_NUMBER: _ClassVar[int]
    CLUSTER_SIZES_FIELD_NUMBER: _ClassVar[int]
    CLUSTER_MODEL_VERSION_FIELD_NUMBER: _ClassVar[int]
    ENV_STEPS_FIELD_NUMBER: _ClassVar[int]
    POLICY_LAG_FIELD_NUMBER: _ClassVar[int]
    POLICY_LAG_REQUEST_FIELD_NUMBER: _ClassVar[int]
    BUFFER_MOVED_SHARE_FIELD_NUMBER: _ClassVar[int]
    INSERTS_WAITING_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_WAITING_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    size_episodes: int
    size_transitions: int
    inserts: int
    duplicates: int
    samples: int
    rate_limiter: str
    rejects: _containers.ScalarMap[str, int]
    cluster_sizes: _containers.RepeatedScalarFieldContainer[int]
    cluster_model_version: int
    env_steps: int
    policy_lag: float
    policy_lag_request: float
    buffer_moved_share: float
    inserts_waiting: int
    samples_waiting: int
    def __init__(self, schema_version: _Optional[int] = ..., size_episodes: _Optional[int] = ..., size_transitions: _Optional[int] = ..., inserts: _Optional[int] = ..., duplicates: _Optional[int] = ..., samples: _Optional[int] = ..., rate_limiter: _Optional[str] = ..., rejects: _Optional[_Mapping[str, int]] = ..., cluster_sizes: _Optional[_Iterable[int]] = ..., cluster_model_version: _Optional[int] = ..., env_steps: _Optional[int] = ..., policy_lag: _Optional[float] = ..., policy_lag_request: _Optional[float] = ..., buffer_moved_share: _Optional[float] = ..., inserts_waiting: _Optional[int] = ..., samples_waiting: _Optional[int] = ...) -> None: ...

class Metrics(_message.Message):
    __slots__ = ("schema_version", "service", "step", "values")
    class ValuesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    SERVICE_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    VALUES_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    service: str
    step: int
    values: _containers.ScalarMap[str, float]
    def __init__(self, schema_version: _Optional[int] = ..., service: _Optional[str] = ..., step: _Optional[int] = ..., values: _Optional[_Mapping[str, float]] = ...) -> None: ...

class Reject(_message.Message):
    __slots__ = ("schema_version", "reason", "detail")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    reason: str
    detail: str
    def __init__(self, schema_version: _Optional[int] = ..., reason: _Optional[str] = ..., detail: _Optional[str] = ...) -> None: ...

class RunProgress(_message.Message):
    __slots__ = ("schema_version", "epoch", "epochs", "finished", "cycle", "cycles_per_epoch", "updates", "diverged")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    EPOCH_FIELD_NUMBER: _ClassVar[int]
    EPOCHS_FIELD_NUMBER: _ClassVar[int]
    FINISHED_FIELD_NUMBER: _ClassVar[int]
    CYCLE_FIELD_NUMBER: _ClassVar[int]
    CYCLES_PER_EPOCH_FIELD_NUMBER: _ClassVar[int]
    UPDATES_FIELD_NUMBER: _ClassVar[int]
    DIVERGED_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    epoch: int
    epochs: int
    finished: bool
    cycle: int
    cycles_per_epoch: int
    updates: int
    diverged: bool
    def __init__(self, schema_version: _Optional[int] = ..., epoch: _Optional[int] = ..., epochs: _Optional[int] = ..., finished: _Optional[bool] = ..., cycle: _Optional[int] = ..., cycles_per_epoch: _Optional[int] = ..., updates: _Optional[int] = ..., diverged: _Optional[bool] = ...) -> None: ...

class ClustererStateRequest(_message.Message):
    __slots__ = ("schema_version",)
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    def __init__(self, schema_version: _Optional[int] = ...) -> None: ...

class ClustererState(_message.Message):
    __slots__ = ("schema_version", "failed_goals", "failures_seen", "episodes_seen", "model_version")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    FAILED_GOALS_FIELD_NUMBER: _ClassVar[int]
    FAILURES_SEEN_FIELD_NUMBER: _ClassVar[int]
    EPISODES_SEEN_FIELD_NUMBER: _ClassVar[int]
    MODEL_VERSION_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    failed_goals: Array
    failures_seen: int
    episodes_seen: int
    model_version: int
    def __init__(self, schema_version: _Optional[int] = ..., failed_goals: _Optional[_Union[Array, _Mapping]] = ..., failures_seen: _Optional[int] = ..., episodes_seen: _Optional[int] = ..., model_version: _Optional[int] = ...) -> None: ...

class ReplayState(_message.Message):
    __slots__ = ("schema_version", "next_episode_id", "first_held_id", "failures", "recent_failed_goals", "o_stats", "g_stats", "cluster_model", "lockstep_versions", "lockstep_counts")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    NEXT_EPISODE_ID_FIELD_NUMBER: _ClassVar[int]
    FIRST_HELD_ID_FIELD_NUMBER: _ClassVar[int]
    FAILURES_FIELD_NUMBER: _ClassVar[int]
    RECENT_FAILED_GOALS_FIELD_NUMBER: _ClassVar[int]
    O_STATS_FIELD_NUMBER: _ClassVar[int]
    G_STATS_FIELD_NUMBER: _ClassVar[int]
    CLUSTER_MODEL_FIELD_NUMBER: _ClassVar[int]
    LOCKSTEP_VERSIONS_FIELD_NUMBER: _ClassVar[int]
    LOCKSTEP_COUNTS_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    next_episode_id: int
    first_held_id: int
    failures: int
    recent_failed_goals: Array
    o_stats: NormalizerStats
    g_stats: NormalizerStats
    cluster_model: ClusterModel
    lockstep_versions: _containers.RepeatedScalarFieldContainer[int]
    lockstep_counts: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, schema_version: _Optional[int] = ..., next_episode_id: _Optional[int] = ..., first_held_id: _Optional[int] = ..., failures: _Optional[int] = ..., recent_failed_goals: _Optional[_Union[Array, _Mapping]] = ..., o_stats: _Optional[_Union[NormalizerStats, _Mapping]] = ..., g_stats: _Optional[_Union[NormalizerStats, _Mapping]] = ..., cluster_model: _Optional[_Union[ClusterModel, _Mapping]] = ..., lockstep_versions: _Optional[_Iterable[int]] = ..., lockstep_counts: _Optional[_Iterable[int]] = ...) -> None: ...
