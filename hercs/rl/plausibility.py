"""Which values an episode may bring into the running normalisers (issue 57: one episode of
3e38-valued observations, finite and well formed, took a FetchReach run from 1.00 to 0.00 for
good, because the normaliser's sums never forget it).

The bounds, per dimension, against the statistics before the episode (`Normalizer`, std floored
at its eps):

- **Implausible**: |v − mean| > `IMPLAUSIBLE_SIGMAS` · std. The episode is refused whole. A
  policy sees at most `ddpg.norm_clip` (5) std of any value, so nothing it can learn from lies
  that far out; an honest state that does is a new region of the task (an object pushed off the
  table moves its z by ~0.4 m against a floored std of 0.01, 40 std; a tipped object's Euler
  angle by π, 314 std), not three orders of magnitude past it.
- **Winsorised**: what the sums take of an admitted episode is clipped to mean ±
  `WINSOR_SIGMAS` · std. That is past a PickAndPlace lift (0.45 m against the floored 0.01,
  45 std), so positions are taken as the reference takes them; a first tipped object's angle
  (314 std) counts at the edge in the sums, and only there (it is stored as it came). One
  episode of T values at the edge adds at most WINSOR_SIGMAS² · std² · T / n to a dimension's
  variance after n samples: with the defaults (200 episodes of T = 50 an epoch) 10 std² after
  epoch 5 (n = 50 000) and 1 std² after epoch 50, where the 3e38 episode, clipped to ±200
  only, adds 200² · 50 / 50 000 = 40 to a variance of 0.01 at epoch 5 (its std × 60). A
  stream of crafted episodes each just inside the bounds can still move the statistics; what
  keeps such a sender out is TLS and the actor certificate (docs/SECURITY.md).
- Both apply once the statistics rest on `WARMUP_SAMPLES` samples (20 episodes of 50 steps);
  before that the only bound is the reference's ±`ddpg.clip_obs` (200), so a run's first
  episodes are trusted as the reference trusts them (docs/FAULTS.md).
"""

from __future__ import annotations

import numpy as np

from hercs.rl.normalizer import Normalizer

IMPLAUSIBLE_SIGMAS = 1000.0
WINSOR_SIGMAS = 100.0
WARMUP_SAMPLES = 1000


def implausible(norm: Normalizer, values: np.ndarray, *, what: str) -> str | None:
    """Why `values` (…, size) lie beyond what `norm`'s statistics make plausible, or None."""
    if norm.count < WARMUP_SAMPLES:
        return None
    v = np.asarray(values, np.float64).reshape(-1, norm.size)
    distance = np.abs(v - norm.mean) / norm.std
    worst = np.unravel_index(int(np.argmax(distance)), distance.shape)
    if not distance[worst] > IMPLAUSIBLE_SIGMAS:
        return None
    dim = int(worst[1])
    return (f"{what}[..., {dim}] = {v[worst]:.3g} lies {distance[worst]:.3g} std from the "
            f"running mean {norm.mean[dim]:.3g} (std {norm.std[dim]:.3g}; at most "
            f"{IMPLAUSIBLE_SIGMAS:g} std after {norm.count} samples, hercs.rl.plausibility)")


def winsorised(norm: Normalizer, values: np.ndarray) -> np.ndarray:
    """`values` clipped to mean ± WINSOR_SIGMAS · std once `norm` is past its warm-up: what
    the normaliser's sums take."""
    v = np.asarray(values, np.float64)
    if norm.count < WARMUP_SAMPLES:
        return v
    reach = WINSOR_SIGMAS * norm.std
    return np.clip(v, norm.mean - reach, norm.mean + reach)
