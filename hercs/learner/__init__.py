"""The learner service: DDPG updates, target nets, checkpoints, weight broadcast.

`hercs.learner.ddpg` is the pure core (no Zenoh); the service module wraps it.
"""

from hercs.learner.ddpg import DDPGLearner, critic_target

__all__ = ["DDPGLearner", "critic_target"]
