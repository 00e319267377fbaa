"""`hercs view --episodes`: which of a log's episodes to draw (ids, ranges, `last:N`,
`spread:N`, `all`; by default the last epoch's)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from hercs.errors import HercsError

FALLBACK_EPISODES_PER_EPOCH = 200
"""Without --episodes the view draws the last epoch's episodes; this many when the run's
config.yaml cannot tell how many an epoch has (the reference's 50 cycles × 4 episodes)."""


class ViewError(HercsError):
    """The log cannot be shown as asked; the message says what to change."""


def parse_selection(text: str) -> list[tuple[str, int | None, int | None, int]]:
    """Parse `--episodes`: comma-separated items, each one of

        N          the episode with id N
        A:B        ids A ≤ id < B (either bound may be omitted)
        A:B:S      every S-th id from A (S ≥ 1)
        last:N     the last N episodes of the log
        spread:N   every n-th episode so that at most N are drawn, plus the last one
        all        every episode

    Returns a list of ("ids", start, stop, step), ("last", None, None, n) and
    ("spread", None, None, n) items.
    Raises ValueError with a message naming the bad item.
    """
    items: list[tuple[str, int | None, int | None, int]] = []
    for raw in text.split(","):
        item = raw.strip()
        try:
            if not item:
                raise ValueError("empty item")
            if item == "all":
                items.append(("ids", None, None, 1))
            elif item.startswith(("last:", "spread:")):
                kind, _, count = item.partition(":")
                n = int(count)
                if n < 1:
                    raise ValueError("N must be ≥ 1")
                items.append((kind, None, None, n))
            elif ":" in item:
                parts = item.split(":")
                if len(parts) > 3:
                    raise ValueError("too many ':'")
                start = int(parts[0]) if parts[0] else None
                stop = int(parts[1]) if parts[1] else None
                step = int(parts[2]) if len(parts) == 3 and parts[2] else 1
                if step < 1 or (start is not None and start < 0) or (stop is not None
                                                                      and stop < 0):
                    raise ValueError("bounds must be ≥ 0 and the step ≥ 1")
                items.append(("ids", start, stop, step))
            else:
                n = int(item)
                if n < 0:
                    raise ValueError("ids are ≥ 0")
                items.append(("ids", n, n + 1, 1))
        except ValueError as exc:
            raise ValueError(
                f"--episodes: bad item {item!r} ({exc}); use ids and ranges like '0:100', "
                "'5,7,9', '0:2000:10', 'last:20', 'spread:200' or 'all'") from None
    return items


def select_episodes(text: str | None, ids: Sequence[int], *,
                    last_epoch: int = FALLBACK_EPISODES_PER_EPOCH) -> list[int]:
    """The episode ids to draw, in log order. `text` is the `--episodes` value; None means the
    last epoch's episodes (`last_epoch` of them): a readable picture of where training is,
    each trajectory coloured by the cluster model of its time."""
    if text is None:
        return list(ids[-last_epoch:])
    chosen: set[int] = set()
    for kind, start, stop, step in parse_selection(text):
        if kind == "last":
            chosen.update(ids[-step:])
            continue
        if kind == "spread":
            chosen.update(ids[::math.ceil(len(ids) / step)] if ids else [])
            chosen.update(ids[-1:])
            continue
        lo = 0 if start is None else start
        for i in ids:
            if i >= lo and (stop is None or i < stop) and (i - lo) % step == 0:
                chosen.add(i)
    return [i for i in ids if i in chosen]
