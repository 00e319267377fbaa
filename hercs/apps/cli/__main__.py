"""`python -m hercs.apps.cli`: the `hercs` command."""

from hercs.apps.cli.main import main

raise SystemExit(main())
