"""Schema version of hercs/proto/hercs.proto. Bump it with any incompatible change to the messages;
receivers reject a message whose `schema_version` differs."""

SCHEMA_VERSION = 1
