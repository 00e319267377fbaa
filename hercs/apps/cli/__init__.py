"""The `hercs` command and `hercs.launch`, its Python form: parser, flags, services."""
