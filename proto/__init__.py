"""The wire: message types (hercs.proto), array codec, validation and key expressions."""

from proto.schema import SCHEMA_VERSION

__all__ = ["SCHEMA_VERSION"]
