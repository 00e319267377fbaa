"""studies/precision_parity/precision_band.py: the band rule on runs written here (a seed inside,
one outside)."""

from __future__ import annotations

from pathlib import Path

import yaml

from hercs.run.rundir import RunDir
from tests.support import load_module

parity = load_module("studies.precision_parity.precision_band")


def _run(root: Path, name: str, seed: int, success: list[float], precision: str) -> None:
    run = root / name
    run.mkdir()
    RunDir(run).config.write_text(yaml.safe_dump({
        "run": {"method": "her-ebp-cs", "seed": seed}, "task": {"name": "push"},
        "learner": {"precision": precision}}))
    rows = ["epoch,success_rate"] + [f"{e},{s}" for e, s in enumerate(success, start=1)]
    RunDir(run).metrics.write_text("\n".join(rows) + "\n")


def test_a_seed_inside_the_fp32_band_passes_and_one_that_lags_does_not(tmp_path: Path) -> None:
    epochs = 20
    ramp = [min(1.0, e / 10) for e in range(epochs)]  # 0.0, 0.1, … 1.0 from epoch 11
    _run(tmp_path, "fp32-s1", 1, [max(0.0, v - 0.1) for v in ramp], "fp32")
    _run(tmp_path, "fp32-s2", 2, [min(1.0, v + 0.1) for v in ramp], "fp32")
    _run(tmp_path, "bf16-s1", 1, ramp, "bf16")  # between the two fp32 seeds throughout
    fp32, bf16 = parity.load_pair(tmp_path, "push", "her-ebp-cs")
    assert sorted(c.seed for c in fp32) == [1, 2] and [c.seed for c in bf16] == [1]
    text, passed = parity.report(fp32, bf16, last_epoch=epochs, tolerance=0.0, command="t")
    assert passed and "| bf16 seed 1 | 20/20 (100%) | 0 | 0 |" in text

    # a seed 5 epochs late: outside the band while the others climb, so the rule refuses it
    _run(tmp_path, "bf16-s2", 2, [0.0] * 5 + ramp[:-5], "bf16")
    fp32, bf16 = parity.load_pair(tmp_path, "push", "her-ebp-cs")
    compared, seeds = parity.compare(fp32, bf16, last_epoch=epochs)
    late = seeds[1]
    assert len(compared) == epochs and late.seed == 2 and late.inside < late.compared
    assert late.above == 0  # all its epochs outside the band are below it
    assert late.at_half is not None and late.at_half > seeds[0].at_half  # type: ignore[operator]
    text, passed = parity.report(fp32, bf16, last_epoch=epochs, tolerance=0.1, command="t")
    assert not passed and "outside the fp32 band" in text


def test_the_command_writes_table_and_figure_and_refuses_missing_runs(tmp_path: Path,
                                                                      capsys) -> None:
    runs, out = tmp_path / "runs", tmp_path / "out"
    runs.mkdir()
    assert parity.main(["--runs", str(runs), "--out", str(out)]) == 2
    assert "need fp32 and bf16 runs (got 0 and 0)" in capsys.readouterr().err
    _run(runs, "a", 1, [0.1, 0.5, 0.9], "fp32")
    _run(runs, "b", 1, [0.1, 0.5, 0.9], "bf16")
    assert parity.main(["--runs", str(runs), "--out", str(out), "--epochs", "3"]) == 0
    assert "| bf16 seed 1 | 3/3 (100%) | 0 | 0 |" in (out / "bf16_parity.md").read_text()
    assert (out / "bf16_parity.png").stat().st_size > 10_000
