"""Zenoh key expressions, all under `hercs/<run>/` (docs/DESIGN.md §3)."""

from __future__ import annotations

from dataclasses import dataclass

ROOT = "hercs"


@dataclass(frozen=True)
class RunKeys:
    run: str

    def _key(self, suffix: str) -> str:
        return f"{ROOT}/{self.run}/{suffix}"

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.run}"

    @property
    def insert(self) -> str:
        return self._key("replay/insert")

    @property
    def sample(self) -> str:
        return self._key("replay/sample")

    @property
    def inserted(self) -> str:
        return self._key("replay/inserted")

    @property
    def episode(self) -> str:
        """Queryable: `EpisodeRequest` → the stored `Episode` with that id (the live view)."""
        return self._key("replay/episode")

    @property
    def status(self) -> str:
        """The replay's `ReplayStatus`, put about once a second (views, `hercs up`)."""
        return self._key("replay/status")

    @property
    def status_at(self) -> str:
        """Queryable (replay): `ReplayStatusRequest` → the `ReplayStatus` of the moment a
        batch was drawn (the learner's epoch rows)."""
        return self._key("replay/status_at")

    @property
    def cluster_model(self) -> str:
        return self._key("cluster/model")

    @property
    def config(self) -> str:
        """Queryable answering with the run's resolved config (YAML), for remote actors."""
        return self._key("config")

    @property
    def clusterer_state(self) -> str:
        """Queryable (replay): `ClustererStateRequest` → `ClustererState`, so that a restarted
        clusterer continues the run's failed-goal buffer and model versions."""
        return self._key("replay/clusterer_state")

    @property
    def progress(self) -> str:
        """The learner's `RunProgress` (latest kept): remote actors exit when it says
        finished."""
        return self._key("run/progress")

    @property
    def weights(self) -> str:
        return self._key("weights")

    @property
    def eval_request(self) -> str:
        """The learner asks again for an overdue evaluation: a `Weights` (evaluate=True) of an
        epoch already broadcast on `weights`."""
        return self._key("eval/request")

    @property
    def eval_result(self) -> str:
        return self._key("eval/result")

    def metrics(self, service: str) -> str:
        return self._key(f"metrics/{service}")

    @property
    def all_metrics(self) -> str:
        return self._key("metrics/**")

    def alive(self, role: str, ident: str) -> str:
        return self._key(f"alive/{role}/{ident}")

    @property
    def all_alive(self) -> str:
        return self._key("alive/**")
