"""studies/authors_peer/published_models.py: their saved actors read without running code,
their test protocol on our simulators, their curves' last epochs; with a checkout named by
HERCS_AUTHORS_CHECKOUT, the CLI on their own files."""

from __future__ import annotations

import csv
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from studies.authors_peer import published_models as pm

REPO = Path(__file__).resolve().parents[3]
CHECKOUT = os.environ.get("HERCS_AUTHORS_CHECKOUT", "")
OBS, GOAL, ACTION = 25, 3, 4

def _checkout_with_a_model(root: Path, seed: int = 121) -> Path:
    """A folder laid out as theirs, with a model file saved the way their ddpg_agent saves."""
    torch.manual_seed(seed)
    layers = {"fc1": (256, OBS + GOAL), "fc2": (256, 256), "fc3": (256, 256),
              "action_out": (ACTION, 256)}
    weights = {}
    for name, shape in layers.items():
        weights[f"{name}.weight"] = torch.randn(shape) * 0.05
        weights[f"{name}.bias"] = torch.zeros(shape[0])
    rng = np.random.default_rng(seed)
    norm = [rng.normal(size=OBS).astype(np.float32), np.ones(OBS, np.float32),
            rng.normal(size=GOAL).astype(np.float32), np.ones(GOAL, np.float32)]
    (root / pm.MODELS).mkdir(parents=True)
    torch.save([*norm, weights], root / pm.MODELS / f"model{seed}.pt")
    return root


class RunsAShellCommand:
    """What a hostile pickle holds: unpickling it would run `touch <marker>`."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (os.system, (f"touch {self.marker}",))


def test_a_model_file_that_would_run_code_is_refused_and_runs_nothing(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    hostile = tmp_path / "model121.pt"
    torch.save([np.zeros(3, np.float32)] * 4 + [{"x": RunsAShellCommand(marker)}], hostile)
    with pytest.raises(pickle.UnpicklingError, match="system"):
        pm.load_pickled_model(hostile)
    assert not marker.exists()


def test_their_format_is_read_with_its_normaliser_and_weights(tmp_path: Path) -> None:
    root = _checkout_with_a_model(tmp_path)
    o_mean, o_std, g_mean, g_std, weights = pm.load_pickled_model(root / pm.MODELS
                                                                  / "model121.pt")
    assert (o_mean.shape, o_std.shape, g_mean.shape, g_std.shape) == ((OBS,), (OBS,),
                                                                      (GOAL,), (GOAL,))
    assert weights["fc1.weight"].shape == (256, OBS + GOAL)
    other = tmp_path / "other.pt"
    torch.save({"not": "theirs"}, other)
    with pytest.raises(ValueError, match="not their"):
        pm.load_pickled_model(other)


def test_their_protocol_on_our_v4_is_the_same_episodes_every_time(tmp_path: Path) -> None:
    root = _checkout_with_a_model(tmp_path)
    model = pm.PublishedModel(root / pm.MODELS / "model121.pt")
    action = model.act(np.zeros(OBS), np.zeros(GOAL))
    assert action.shape == (ACTION,) and np.all(np.abs(action) <= 1.0)
    first, second = (pm.success_rate(model, "v4", 3) for _ in range(2))
    assert first == second  # the same reset seeds: the same episodes


def test_their_actor_is_built_here_and_takes_only_their_layers(tmp_path: Path) -> None:
    root = _checkout_with_a_model(tmp_path)
    *_, weights = pm.load_pickled_model(root / pm.MODELS / "model121.pt")
    actor = pm.their_actor(weights)
    x = torch.randn(5, OBS + GOAL)
    w = {k: v.float() for k, v in weights.items()}
    hidden = x
    for name in ("fc1", "fc2", "fc3"):  # their forward: three ReLU layers, then tanh
        hidden = torch.relu(hidden @ w[f"{name}.weight"].T + w[f"{name}.bias"])
    expected = torch.tanh(hidden @ w["action_out.weight"].T + w["action_out.bias"])
    torch.testing.assert_close(actor(x).detach(), expected)
    with pytest.raises(ValueError, match="not their actor's layers"):
        pm.their_actor({**weights, "fc4.weight": weights["fc3.weight"]})
    with pytest.raises(RuntimeError, match="size mismatch"):
        pm.their_actor({**weights, "fc2.bias": torch.zeros(7)})


def test_the_wilson_interval_holds_its_share_and_stays_in_zero_one() -> None:
    for k, n in ((0, 10), (10, 10), (974, 1000), (1, 2)):
        low, high = pm.wilson(k, n)
        assert 0.0 <= low <= k / n <= high <= 1.0
    assert pm.wilson(974, 1000)[1] - pm.wilson(974, 1000)[0] < pm.wilson(39, 40)[1] - \
        pm.wilson(39, 40)[0]  # more episodes, a narrower interval


def test_their_last_epochs_are_the_mean_of_each_curves_last_ten() -> None:
    rows = [r for r in csv.DictReader(pm.PUBLISHED.open())
            if r["task"] == "FetchPickAndPlace" and r["method"] == "her-cs" and r["seed"] == "133"]
    last = sorted(rows, key=lambda r: int(r["epoch"]))[-pm.LAST_EPOCHS:]
    assert [int(r["epoch"]) for r in last] == list(range(191, 201))
    means, last_epoch = pm.published_last_epochs()
    assert last_epoch == 200
    assert means["her-cs"][133] == pytest.approx(np.mean([float(r["success_rate"]) for r in last]))


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "studies.authors_peer.published_models", *args],
                          cwd=REPO, capture_output=True, text=True, timeout=300)


def test_a_folder_without_their_models_and_a_bad_count_are_refused(tmp_path: Path) -> None:
    missing = _cli("--checkout", str(tmp_path), "--out", str(tmp_path / "out"))
    assert missing.returncode == 2 and "model<seed>.pt for seeds [121, 123" in missing.stderr
    bad = _cli("--checkout", str(tmp_path), "--episodes", "0")
    assert bad.returncode == 2 and "--episodes 0" in bad.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not CHECKOUT, reason="HERCS_AUTHORS_CHECKOUT names no checkout of the "
                    "authors' repository (their saved models are in it)")
def test_their_own_model_on_both_simulators(tmp_path: Path) -> None:
    done = _cli("--checkout", CHECKOUT, "--quick", "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "authors_models.json").read_text())
    assert summary["seeds"] == [121] and summary["episodes"] == 2
    for version in ("v1", "v4"):
        r = summary["results"]["121"][version]
        assert r["low"] <= r["success"] <= r["high"]
    assert "| 121 |" in (tmp_path / "authors_models.md").read_text()
