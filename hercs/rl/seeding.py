"""Per-node random generators split from one root seed (Acme-style).

Each service, actor and component asks for its own stream by name, e.g.
`generator(seed, "actor", "3")`; streams are independent and reproducible. Nothing in hercs
uses the global `np.random` or `torch` RNG state.
"""

from __future__ import annotations

import hashlib

import numpy as np


def _entropy(names: tuple[str, ...]) -> list[int]:
    digest = hashlib.sha256("/".join(names).encode()).digest()
    return [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]


def seed_sequence(root_seed: int, *names: str) -> np.random.SeedSequence:
    return np.random.SeedSequence([root_seed, *_entropy(names)])


def generator(root_seed: int, *names: str) -> np.random.Generator:
    """An independent numpy Generator for the node called `names` under `root_seed`."""
    return np.random.default_rng(seed_sequence(root_seed, *names))


def int_seed(root_seed: int, *names: str) -> int:
    """A 31-bit integer seed (for torch, scikit-learn, env.reset) for the node `names`."""
    return int(seed_sequence(root_seed, *names).generate_state(1, np.uint32)[0] & 0x7FFFFFFF)
