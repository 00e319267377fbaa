"""The service roles of a run, defined once: the process each runs, how `hercs up` starts and
stops it, and where it is deployed. The CLI, the launcher, the ACL and certificates, compose
and Slurm all read this table."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ServiceRole:
    name: str
    """The CLI command, the certificate's common name and the ACL's user."""
    module: str
    """The process shell: `run(config, *, ident) -> int`, imported only when used."""
    summary: str
    """`hercs --help`'s line."""
    example: str
    """How one joins a run by hand."""
    stop_stage: int
    """`hercs up` stops the stages in order: 0 the actors (episodes stop), 1 the rest, 2 the
    replay last (it makes every acknowledged episode durable)."""
    optional: bool = False
    """Started by `hercs up` only with `view.live`, and its death never ends the run (the
    live view: watching training must never stop it)."""
    hard_exit: bool = True
    """Its process ends with `os._exit` after its orderly close (not the live view: the Rerun
    SDK flushes its recording in an exit handler)."""
    compose: bool = True
    """A service of docker-compose.yml (the live view is `hercs up --rerun`'s)."""
    actor_node: bool = False
    """Runs on the actors' nodes (Slurm's second component), not beside the learner."""


SERVICE_ROLES: dict[str, ServiceRole] = {r.name: r for r in (
    ServiceRole("replay", "hercs.replay_service.replay_shell",
                "run the replay service (episode store, HER, samplers)",
                "hercs replay --connect tcp/127.0.0.1:7447 --run myrun --task push",
                stop_stage=2),
    ServiceRole("live", "hercs.apps.views.live_view",
                "stream a run to Rerun while it trains (what `hercs up --rerun` starts; join "
                "a run with --connect and --run)",
                "hercs live --connect tcp/LEARNER_HOST:7447 --run myrun --rerun",
                stop_stage=1, optional=True, hard_exit=False, compose=False),
    ServiceRole("clusterer", "hercs.clusterer.clusterer_shell",
                "run the clusterer (failed goals, k-means refits)",
                "hercs clusterer --connect tcp/127.0.0.1:7447 --run myrun --task push",
                stop_stage=1),
    ServiceRole("learner", "hercs.learner.learner_shell",
                "run the DDPG learner (updates, weights, epochs)",
                "hercs learner --connect tcp/127.0.0.1:7447 --run myrun --task push",
                stop_stage=1),
    ServiceRole("evaluator", "hercs.actors.evaluator",
                "run the evaluator (deterministic test episodes)",
                "hercs evaluator --connect tcp/127.0.0.1:7447 --run myrun --task push",
                stop_stage=1),
    ServiceRole("actor", "hercs.actors.actor_shell",
                "run a rollout actor (join a run with --connect and --run)",
                "hercs actor --connect tcp/LEARNER_HOST:7447 --run myrun",
                stop_stage=0, actor_node=True),
)}
"""In `hercs up`'s start order: the replay alone first (it serves the config and the insert
queryable), then the live view if enabled (before any episode is made), the actors last."""

ROLES = tuple(SERVICE_ROLES)
"""Every role's name, in start order."""
