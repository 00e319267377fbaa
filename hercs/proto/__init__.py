"""The wire schema: the message types (hercs.proto and its generated hercs_pb2), the schema
version (schema.py) and every key expression of a run (keys.py). The array codec and the
message checks live above it, in hercs.wire.codec and hercs.wire.validation."""

from hercs.proto.schema import SCHEMA_VERSION

__all__ = ["SCHEMA_VERSION"]
