"""studies/lag_audit: a run that recorded a lag shifted by a resume is found, with the shift
and the lag it implies; a clean run and a run whose lag really rose are not listed."""

from __future__ import annotations

from pathlib import Path

import yaml

from studies.lag_audit.__main__ import main

COLUMNS = "epoch,success_rate,policy_lag,policy_lag_p50,policy_lag_max"
SETTING = {"learner": {"prefetch_depth": 3},
           "training": {"max_policy_lag": 3, "schedule": "async"},
           "actor": {"insert_queue": 2}}


def _run(root: Path, name: str, lags: list[tuple[float, float, float]]) -> None:
    run = root / name
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump(
        {"run": {"method": "her-cs", "seed": 1}, "task": {"name": "pick"}, **SETTING}))
    (run / "metrics.csv").write_text(COLUMNS + "\n" + "".join(
        f"{e},0.1,{m},{p},{x}\n" for e, (m, p, x) in enumerate(lags, start=1)))


def test_a_shifted_piece_is_found_with_the_lag_it_implies(tmp_path: Path) -> None:
    steady = (2.5, 2.0, 3.0)
    _run(tmp_path, "clean", [steady] * 10)
    # resumed in epoch 4 with 36 cycles beyond the checkpoint: the resume's epoch mixes lives
    _run(tmp_path, "resumed", [steady] * 3 + [(-20.0, -34.0, 2.0)] + [(-33.5, -34.0, -33.0)] * 6)
    _run(tmp_path, "learner-restart", [steady] * 4 + [(40.0, 40.0, 45.0)] + [steady] * 5)
    out = tmp_path / "audit.md"
    assert main(["--runs", str(tmp_path), "-o", str(out)]) == 0
    rows = [line for line in out.read_text().splitlines() if line.startswith("| ")][1:]
    assert rows == ["| resumed | 1–3 | 2.5 / 2 / 3 | +0 | 2.5 / 3 | 3 |",
                    "| resumed | 4–10 | -33.5 / -34 / -33 | +36 | 2.5 / 3 | 3 |"]
    assert "1 runs recorded a shifted lag" in out.read_text()
