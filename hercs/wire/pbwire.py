"""Protobuf wire-format pieces for the two hot paths that assemble messages from parts.

A message may be written as its constant part's bytes (serialised once by protobuf) followed by
the fields that change; the replay's sample replies and the episode log's scene messages do
so, where building one protobuf object per message cost more than the rest of the path.
Field numbers come from the descriptors, so a schema change cannot silently shift them; tests
parse what these functions build.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np


class Descriptor(Protocol):
    """A message descriptor (`Message.DESCRIPTOR`, protobuf's pure-Python or upb one)."""

    @property
    def full_name(self) -> str: ...

    @property
    def fields_by_name(self) -> Mapping[str, Any]: ...


VARINT, FIXED64, LENGTH_DELIMITED = 0, 1, 2
"""Wire types used here (protobuf encoding spec)."""


def varint(value: int) -> bytes:
    """Protobuf's base-128 varint of a non-negative integer."""
    if value < 0:
        raise ValueError(f"varint: {value} is negative (only unsigned values are encoded here)")
    out = bytearray()
    while value > 0x7F:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


SMALL_VARINTS = [varint(value) for value in range(1 << 14)]
"""`varint(n)` for n < 16384 (lengths inside a message), looked up instead of computed."""


def field_key(message: Descriptor, name: str, wire_type: int) -> bytes:
    """The key (field number and wire type) of `message.name`, checked against its type."""
    field = message.fields_by_name[name]
    expected = {field.TYPE_DOUBLE: FIXED64, field.TYPE_FIXED64: FIXED64,
                field.TYPE_MESSAGE: LENGTH_DELIMITED, field.TYPE_STRING: LENGTH_DELIMITED,
                field.TYPE_BYTES: LENGTH_DELIMITED}.get(field.type, VARINT)
    if expected != wire_type:
        raise TypeError(f"{message.full_name}.{name} has wire type {expected}, not {wire_type}")
    return varint(field.number << 3 | wire_type)


def length_delimited(key: bytes, payload: bytes) -> bytes:
    """One length-delimited field: a sub-message, string or bytes."""
    return key + varint(len(payload)) + payload


class DoubleTriple:
    """Three double fields of a message (a Vector3's x, y, z), each written with its key even
    when it is 0.0 (protobuf would omit it; parsing gives the same message)."""

    def __init__(self, message: Descriptor, names: tuple[str, str, str] = ("x", "y", "z")
                 ) -> None:
        keys = [field_key(message, name, FIXED64) for name in names]
        if any(len(key) != 1 for key in keys):
            raise ValueError(f"{message.full_name}{names}: keys longer than one byte")
        self._keys = tuple(key[0] for key in keys)
        self._struct = struct.Struct("<BdBdBd")

    def pack(self, x: float, y: float, z: float) -> bytes:
        k0, k1, k2 = self._keys
        return self._struct.pack(k0, x, k1, y, k2, z)


class TimestampField:
    """A `google.protobuf.Timestamp` field of a message, from nanoseconds since the epoch."""

    def __init__(self, message: Descriptor, name: str = "timestamp") -> None:
        self._key = field_key(message, name, LENGTH_DELIMITED)
        stamp = message.fields_by_name[name].message_type
        kind = "scalar" if stamp is None else stamp.full_name
        if kind != "google.protobuf.Timestamp":
            raise TypeError(f"{message.full_name}.{name} is a {kind}")
        self._seconds = field_key(stamp, "seconds", VARINT)
        self._nanos = field_key(stamp, "nanos", VARINT)

    def encode(self, time_ns: int) -> bytes:
        seconds, nanos = divmod(time_ns, 1_000_000_000)
        return length_delimited(self._key, self._seconds + varint(seconds)
                                + self._nanos + varint(nanos))

    def encode_many(self, times_ns: Sequence[int]) -> list[bytes]:
        """`encode` of each time: the nanos' varints (at most 5 bytes, < 2^30) computed
        together with numpy, each distinct second's once (an episode spans a few seconds)."""
        seconds, nanos = np.divmod(np.asarray(times_ns, dtype=np.int64), 1_000_000_000)
        if len(times_ns) and seconds.min() < 0:
            raise ValueError("TimestampField.encode_many: times before the epoch")
        groups = (nanos[:, None] >> np.arange(0, 35, 7)) & 0x7F
        widths = 1 + (nanos[:, None] >= (1 << np.arange(7, 35, 7))).sum(axis=1)
        groups[:, :-1] |= 0x80 * (np.arange(1, 5) < widths[:, None])
        packed = groups.astype(np.uint8).tobytes()
        # per (second, nanos width): everything before the nanos' varint, built once
        heads = {}
        for second, width in set(zip(seconds.tolist(), widths.tolist(), strict=True)):
            inner = self._seconds + varint(second) + self._nanos
            heads[second, width] = self._key + varint(len(inner) + width) + inner
        out = [heads[key] + packed[5 * i:5 * i + key[1]] for i, key in enumerate(
            zip(seconds.tolist(), widths.tolist(), strict=True))]
        return out
