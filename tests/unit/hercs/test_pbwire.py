"""The protobuf wire pieces against protobuf's own serialisation."""

import pytest
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from hypothesis import given
from hypothesis import strategies as st

from hercs.proto import hercs_pb2 as pb
from hercs.wire import pbwire


@given(st.integers(min_value=0, max_value=2**64 - 1))
def test_varint_is_protobufs(value: int) -> None:
    # Batch.request_id is field 2, a uint64: key byte 0x10, then the value as a varint
    encoded = pb.Batch(request_id=value).SerializeToString()
    assert encoded == (b"\x10" + pbwire.varint(value) if value else b"")


def test_varint_refuses_negative_values() -> None:
    with pytest.raises(ValueError, match="-1 is negative"):
        pbwire.varint(-1)


def test_field_key_checks_the_wire_type() -> None:
    assert pbwire.field_key(pb.Batch.DESCRIPTOR, "request_id", pbwire.VARINT) == b"\x10"
    with pytest.raises(TypeError, match=r"Batch\.request_id has wire type 0, not 2"):
        pbwire.field_key(pb.Batch.DESCRIPTOR, "request_id", pbwire.LENGTH_DELIMITED)


finite = st.floats(allow_nan=False, allow_infinity=False)


@given(finite, finite, finite)
def test_double_triple_parses_as_the_vector(x: float, y: float, z: float) -> None:
    parsed = Vector3.FromString(pbwire.DoubleTriple(Vector3.DESCRIPTOR).pack(x, y, z))
    assert parsed == Vector3(x=x, y=y, z=z)


@given(st.integers(min_value=0, max_value=2**63 - 1))
def test_timestamp_field_is_protobufs(time_ns: int) -> None:
    expected = SceneEntity()
    expected.timestamp.FromNanoseconds(time_ns)
    encoded = pbwire.TimestampField(SceneEntity.DESCRIPTOR).encode(time_ns)
    assert SceneEntity.FromString(encoded) == expected
    # protobuf writes the same bytes unless a part is 0 (which it omits)
    if expected.timestamp.seconds and expected.timestamp.nanos:
        assert encoded == expected.SerializeToString()


def test_timestamp_field_refuses_a_non_timestamp() -> None:
    with pytest.raises(TypeError, match=r"foxglove\.SceneEntity\.lifetime is a "
                       r"google\.protobuf\.Duration"):
        pbwire.TimestampField(SceneEntity.DESCRIPTOR, "lifetime")


@given(st.lists(st.integers(min_value=0, max_value=2**63 - 1), max_size=60))
def test_timestamps_encoded_together_are_encoded_one_by_one(times: list[int]) -> None:
    field = pbwire.TimestampField(SceneEntity.DESCRIPTOR)
    assert field.encode_many(times) == [field.encode(t) for t in times]
