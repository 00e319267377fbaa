"""What `pip install` puts on a lab's path: the one package `hercs`, whole (every subpackage, the
.proto file, the authors' reference curves, the console script), and nothing that clashes with a
lab's own `learner` or `proto` (issue: a library that lives beside a lab's code). The wheel is
built from a copy of the sources, as pip builds it, and installed into a folder of its own."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel pip builds from pyproject.toml, README.md and hercs/ (the build reads no more)."""
    src = tmp_path_factory.mktemp("src")
    shutil.copy(REPO / "pyproject.toml", src)
    shutil.copy(REPO / "README.md", src)
    shutil.copytree(REPO / "hercs", src / "hercs",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    out = tmp_path_factory.mktemp("wheel")
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
                           "--no-build-isolation", "--wheel-dir", str(out), str(src)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    [built] = out.glob("hercs-*.whl")
    return built


def test_the_wheel_installs_one_top_level_package_hercs_with_every_subpackage(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    top = {name.split("/")[0] for name in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"hercs"}, sorted(top)
    # every package of the source tree, so none is left out by packages.find
    packages = {str(p.parent.relative_to(REPO)) for p in (REPO / "hercs").rglob("__init__.py")
                if "__pycache__" not in p.parts}
    assert {"hercs/apps", "hercs/actors", "hercs/learner", "hercs/replay_service",
            "hercs/clusterer", "hercs/proto", "hercs/config", "hercs/rl", "hercs/wire",
            "hercs/net", "hercs/run", "hercs/run/runlog"} <= packages
    missing = sorted(p for p in packages if f"{p}/__init__.py" not in names)
    assert missing == [], f"packages missing from the wheel: {missing}"
    assert "hercs/proto/hercs.proto" in names  # package data: the schema beside its code
    assert "hercs/apps/plots/data/authors_success_rates.csv" in names  # hercs plot --reference
    [entry_points] = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    text = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert "hercs = hercs.apps.cli.main:main" in text


def test_hercs_runs_beside_a_labs_own_learner_and_proto(wheel: Path, tmp_path: Path) -> None:
    """A lab's working folder with its own `learner.py` and `proto/` package: both import as
    the lab's, and hercs (its services, the CLI, the wire schema) still works from the wheel."""
    target = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                           "--target", str(target), str(wheel)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lab = tmp_path / "lab"
    (lab / "proto").mkdir(parents=True)
    (lab / "learner.py").write_text("WHOSE = 'lab'\n")
    (lab / "proto" / "__init__.py").write_text("WHOSE = 'lab'\n")
    probe = (
        "import learner, proto\n"
        "import hercs, hercs.apps.cli, hercs.learner.ddpg, hercs.replay_service.table\n"
        "from hercs.proto import hercs_pb2\n"
        "assert learner.WHOSE == 'lab' and proto.WHOSE == 'lab', (learner, proto)\n"
        "assert hercs_pb2.Episode(run='r').run == 'r'\n"
        "from hercs.apps.plots.curves import REFERENCE_CSV, load_reference\n"
        "runs = {(c.task, c.method) for c in load_reference()}\n"
        "assert ('FetchPush', 'her-cs') in runs and len(runs) == 12, runs\n"
        "print(hercs.__file__); print(hercs.learner.ddpg.__file__); print(REFERENCE_CSV)\n"
    )
    # the target folder first on the path, before this checkout's editable install
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(target), "HOME": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", probe], cwd=lab, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    for line in done.stdout.split():
        assert line.startswith(str(target)), done.stdout
    cli = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "--help"], cwd=lab, env=env,
                         capture_output=True, text=True, timeout=120)
    assert cli.returncode == 0 and "up" in cli.stdout, cli.stderr


def test_every_link_in_the_checkout_resolves() -> None:
    """A moved file leaves no dangling link behind (docs/reference/authors_success_rates.csv
    pointed at the data's old folder after the apps split)."""
    listed = subprocess.run(["git", "ls-files", "-s"], cwd=REPO, capture_output=True,
                            text=True)
    if listed.returncode != 0:
        pytest.skip(f"not a git checkout, so no tracked links to check: {listed.stderr.strip()}")
    links = [line.split("\t", 1)[1] for line in listed.stdout.splitlines()
             if line.startswith("120000 ")]  # git's mode for a symbolic link
    dangling = [link for link in links if not (REPO / link).exists()]
    assert not dangling, f"links whose target is gone: {dangling}"
