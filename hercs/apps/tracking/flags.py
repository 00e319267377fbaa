"""`--track NAME`, the flag of `hercs up` and `hercs sweep`, and the override it makes."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from hercs.config import TRACKERS


def add_track_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    parser.add_argument(
        "--track", action="append", choices=TRACKERS, metavar="NAME",
        help=f"send the run to a tracker ({', '.join(TRACKERS)}; repeat for more): each "
             "epoch's metrics and the cluster model's sizes, the resolved config, the commit; "
             "--set tracking.* chooses the project, group, W&B mode, MLflow URI")


def backends_override(configured: Sequence[str], named: Sequence[str]) -> list[str]:
    """`tracking.backends` with the `named` trackers added to the `configured` ones, as a
    `--set` item; none when none is named."""
    if not named:
        return []
    return [f"tracking.backends=[{', '.join(dict.fromkeys([*configured, *named]))}]"]
