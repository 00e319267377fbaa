"""The replay's observation and goal normalisers, which cover every stored episode, and the
plausibility check (hercs.rl.plausibility) an arriving episode passes against them."""

from __future__ import annotations

import numpy as np

from hercs.reasons import Reason
from hercs.replay_service.her import normalizer_sample
from hercs.rl.normalizer import Normalizer, NormalizerState
from hercs.rl.plausibility import implausible, winsorised
from hercs.wire.episode import EpisodeData


class EpisodeNormalizers:
    def __init__(self, *, obs_dim: int, goal_dim: int, eps: float, clip_range: float,
                 clip_obs: float, future_p: float) -> None:
        self.o_norm = Normalizer(obs_dim, eps=eps, clip_range=clip_range)
        self.g_norm = Normalizer(goal_dim, eps=eps, clip_range=clip_range)
        self.clip_obs = clip_obs
        self.future_p = future_p

    def update(self, episode: EpisodeData, rng: np.random.Generator) -> None:
        """Add a stored episode's HER-relabelled sample (`normalizer_sample`), clipped to
        ±clip_obs and winsorised, as the reference updates after each rollout."""
        obs, g = normalizer_sample(episode, future_p=self.future_p, rng=rng)
        clip = self.clip_obs
        self.o_norm.update(winsorised(self.o_norm, np.clip(obs, -clip, clip)))
        self.g_norm.update(winsorised(self.g_norm, np.clip(g, -clip, clip)))
        self.o_norm.recompute_stats()
        self.g_norm.recompute_stats()

    def implausible(self, episode: EpisodeData) -> tuple[Reason, str] | None:
        """Why `episode`'s values lie beyond what the running statistics make plausible, or
        None to admit it."""
        for norm, values, what in ((self.o_norm, episode.obs, "obs"),
                                   (self.g_norm, episode.ag, "achieved_goal"),
                                   (self.g_norm, episode.g, "desired_goal")):
            detail = implausible(norm, values, what=what)
            if detail is not None:
                return Reason.IMPLAUSIBLE, f"episode refused: {detail}"
        return None

    def state(self) -> tuple[NormalizerState, NormalizerState]:
        return self.o_norm.state_dict(), self.g_norm.state_dict()

    def load(self, o_stats: NormalizerState, g_stats: NormalizerState) -> None:
        self.o_norm.load_state_dict(o_stats)
        self.g_norm.load_state_dict(g_stats)
