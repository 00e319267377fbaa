"""Weights messages as the actor and the evaluator take them: parsed, decoded and checked to
load into a policy of the run's task before anything adopts them."""

from __future__ import annotations

from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.rl.policy import Policy, PolicyWeights
from hercs.wire.codec import msg_to_weight_arrays
from hercs.wire.validation import MAX_INT64, parse_message


class WeightsDecoder:
    """Bytes from `keys.weights` → `pb.Weights` (`parse`) → checked `PolicyWeights` (`decode`);
    both raise `InvalidMessage`.

    Beyond the schema and array codec, `decode` loads the weights into a scratch `Policy` of
    this task's sizes (names, shapes, finiteness, positive std), so the `PolicyWeights` it
    returns always loads. Use from one thread.
    """

    def __init__(self, *, scratch: Policy, max_bytes: int) -> None:
        """`scratch`: a policy of the run's task and sizes, used only to check; `max_bytes`:
        the largest message parsed."""
        self._scratch = scratch
        self._max_bytes = max_bytes

    def parse(self, raw: bytes) -> pb.Weights:
        """Schema only (size, protobuf, schema_version): enough to read `evaluate`/`epoch`."""
        return parse_message(raw, pb.Weights, max_bytes=self._max_bytes)

    def decode(self, msg: pb.Weights) -> PolicyWeights:
        if msg.version > MAX_INT64:  # episodes carry it as their int64 policy_version
            raise InvalidMessage(Reason.BAD_VALUE,
                                 f"Weights version {msg.version} is above {MAX_INT64}")
        actor, o_stats, g_stats = msg_to_weight_arrays(msg)
        weights = PolicyWeights(version=int(msg.version), actor=actor, o_stats=o_stats,
                                g_stats=g_stats)
        try:
            self._scratch.load(weights)
        except ValueError as exc:
            raise InvalidMessage(Reason.BAD_VALUE,
                                 f"Weights version {msg.version}: {exc}") from None
        return weights
