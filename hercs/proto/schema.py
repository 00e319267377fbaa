"""Schema version of hercs/proto/hercs.proto. Bump it with any incompatible change to the messages;
receivers reject a message whose `schema_version` differs."""

SCHEMA_VERSION = 1

MAX_BATCH_BYTES = 1 << 30
"""A Batch reply larger than this is refused unread by the learner (40 × 256 FetchPush
transitions: ~2.4 MB); the config's bounds keep every request the learner makes under it."""
