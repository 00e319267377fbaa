"""HER "future" relabelling as pure vectorised functions (no environment, injected RNG).

Matches `her_sampler.sample_her_transitions` of the reference PyTorch HER code, with the same
draws in the same order (`her_indices`) from a Generator; the rule is docs/DESIGN.md §4.2.
Rewards come from `TaskSpec.compute_reward`; `future_t` can be T since ag has T+1 entries.
The samplers choose the episodes; this module takes their slots.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hercs.errors import SamplingError
from hercs.wire.batch import TransitionBatch
from hercs.wire.episode import EpisodeData

RewardFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""reward_fn(achieved_goal_next, desired_goal) -> (B,) rewards, vectorised over the batch."""


class EpisodeArrays(Protocol):
    """Batched episode arrays indexed by slot; `EpisodeStore` satisfies it."""

    @property
    def obs(self) -> np.ndarray: ...  # (N, T+1, obs_dim)
    @property
    def ag(self) -> np.ndarray: ...  # (N, T+1, goal_dim)
    @property
    def g(self) -> np.ndarray: ...  # (N, T, goal_dim)
    @property
    def actions(self) -> np.ndarray: ...  # (N, T, action_dim)


@dataclass(frozen=True)
class HERIndices:
    """The timestep draw and the future relabelling draw for B transitions."""

    t: np.ndarray
    """(B,) int64 in [0, T−1]."""
    future_t: np.ndarray
    """(B,) int64 in [t+1, T]; drawn for every transition, used only where her_mask."""
    her_mask: np.ndarray
    """(B,) bool: the goal of this transition is replaced by ag[future_t]."""


def _f32(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float32, copy=False)


def _rows(per_episode: np.ndarray) -> np.ndarray:
    """(N, S, dim) → (N·S, dim), a view when the array is contiguous (the store's are)."""
    return per_episode.reshape(-1, per_episode.shape[-1])


def her_indices(
    batch_size: int, horizon: int, *, future_p: float, rng: np.random.Generator
) -> HERIndices:
    """Draw t, the HER mask and future_t in the reference's order (t, mask, offset)."""
    t = rng.integers(horizon, size=batch_size)
    her_mask = rng.uniform(size=batch_size) < future_p
    future_offset = (rng.uniform(size=batch_size) * (horizon - t)).astype(np.int64)
    return HERIndices(t=t, future_t=t + 1 + future_offset, her_mask=her_mask)


def relabel(
    arrays: EpisodeArrays,
    episode_idxs: np.ndarray,
    *,
    future_p: float,
    reward_fn: RewardFn,
    rng: np.random.Generator,
) -> TransitionBatch:
    """One HER minibatch from the episodes in `episode_idxs` (slots, repeats allowed)."""
    return relabel_with_draw(arrays, episode_idxs, future_p=future_p, reward_fn=reward_fn,
                             rng=rng)[0]


def relabel_with_draw(
    arrays: EpisodeArrays,
    episode_idxs: np.ndarray,
    *,
    future_p: float,
    reward_fn: RewardFn,
    rng: np.random.Generator,
) -> tuple[TransitionBatch, HERIndices]:
    """`relabel`, and the timestep and future draws that made the minibatch (for tests and
    analyses; only the minibatch leaves the replay)."""
    episode_idxs = np.asarray(episode_idxs, dtype=np.int64)
    ag_all = arrays.ag
    n_episodes, horizon = ag_all.shape[0], ag_all.shape[1] - 1
    if episode_idxs.ndim != 1 or episode_idxs.size == 0:
        raise SamplingError(
            f"relabel: episode_idxs must be a non-empty 1-d array, got shape {episode_idxs.shape}"
        )
    if episode_idxs.min() < 0 or episode_idxs.max() >= n_episodes:
        raise SamplingError(
            f"relabel: episode index {int(episode_idxs.max())} (min {int(episode_idxs.min())}) "
            f"outside the {n_episodes} stored episodes; no batch drawn"
        )
    draw = her_indices(episode_idxs.size, horizon, future_p=future_p, rng=rng)
    ep, t = episode_idxs, draw.t
    # Gathers as `take` on (episodes × steps, dim) views: half the cost of [ep, t] indexing.
    # `take` copies, so the store is never written.
    at_t = ep * (horizon + 1) + t  # row of (ep, t) in the T+1-step arrays (obs, ag)
    obs = _rows(arrays.obs)
    ag = _rows(ag_all)
    g = _rows(arrays.g).take(ep * horizon + t, axis=0)
    mask = draw.her_mask
    g[mask] = ag.take(ep[mask] * (horizon + 1) + draw.future_t[mask], axis=0)
    ag2 = ag.take(at_t + 1, axis=0)
    r = np.asarray(reward_fn(ag2, g), dtype=np.float32).reshape(episode_idxs.size)
    transitions = TransitionBatch(
        o=_f32(obs.take(at_t, axis=0)), g=_f32(g),
        u=_f32(_rows(arrays.actions).take(ep * horizon + t, axis=0)), r=r,
        o2=_f32(obs.take(at_t + 1, axis=0)))
    return transitions, draw


def normalizer_sample(
    episode: EpisodeData, *, future_p: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(obs, g) of T HER-relabelled transitions from `episode`, for the o/g normalisers.

    The reference's `_update_normalizer` does this after storing each rollout batch: it draws
    T (= num_transitions) transitions with the same HER sampler and feeds their o and g
    (clipped to ±clip_obs by the caller, not here) to the running normalisers. Rewards are
    not needed, so none are computed.
    """
    ag = np.asarray(episode.ag)
    horizon = ag.shape[0] - 1
    draw = her_indices(horizon, horizon, future_p=future_p, rng=rng)
    g = np.array(np.asarray(episode.g)[draw.t], dtype=np.float32)
    g[draw.her_mask] = ag[draw.future_t[draw.her_mask]]
    obs = np.asarray(episode.obs, dtype=np.float32)[draw.t]
    return obs, g
