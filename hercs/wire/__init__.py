"""What travels between the services: the protobuf messages' Python forms (episodes, served
batches, transition batches, replay state), their one encode/decode pair each, and the
validation of everything received."""
