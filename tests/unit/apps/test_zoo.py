"""The policy zoo (hercs/apps/evaluation/zoo.py): every shipped best.pt listed with its run's
facts, `zoo:NAME` resolved, the README's block and the committed model cards equal to what
`hercs zoo` generates (so neither goes stale), and what `hercs eval` says of the recorded
success beside its own (hercs/apps/evaluation/recorded.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hercs.apps.cli.main import main
from hercs.apps.evaluation import zoo
from hercs.apps.evaluation.recorded import RecordedSuccess, comparison, wilson_interval

REPO = Path(__file__).resolve().parents[3]
SHIPPED = sorted(p.parent.parent.name for p in (REPO / "docs/results/runs").glob(
    "*/checkpoints/best.pt"))


@pytest.fixture(scope="module")
def entries() -> list[zoo.ZooEntry]:
    return zoo.shipped()


def test_the_zoo_lists_every_shipped_policy_with_its_runs_facts(entries) -> None:
    assert [e.name for e in entries] == SHIPPED and len(SHIPPED) >= 4
    pick = next(e for e in entries if e.name == "pick-her-cs-s1")
    assert (pick.config.task.name, pick.config.run.method, pick.env_id, pick.epoch) == (
        "pick", "her-cs", "FetchPickAndPlace-v4", 78)
    assert pick.recorded_short == "0.80 (16/20)" and pick.best_of == 100
    assert (pick.commit, pick.machine_short) == ("c2a3187", "Intel Xeon")
    assert all(e.simulator.startswith("mujoco-py") == (e.config.task.env_version == "v1")
               for e in entries)
    lines = zoo.table(entries).splitlines()
    assert lines[0].split() == list(zoo.COLUMNS) and len(lines) == len(SHIPPED) + 1


def test_the_readmes_list_is_the_generated_one(entries) -> None:
    block = zoo.readme_block((REPO / "README.md").read_text())
    assert block == zoo.markdown(entries), (
        "README.md's shipped policies are stale: paste `hercs zoo --markdown` between its "
        "zoo markers")


def test_each_shipped_policy_has_its_generated_model_card(entries, tmp_path: Path) -> None:
    committed = REPO / "docs/results/zoo"
    assert sorted(p.stem for p in committed.glob("*.md")) == SHIPPED
    for entry in entries:  # the cards' folder beside the runs': links go to ../runs
        assert (committed / f"{entry.name}.md").read_text() == zoo.model_card(entry), (
            f"{entry.name}.md is stale: run `hercs zoo --cards docs/results/zoo`")
    written = zoo.write_cards(entries[:1], tmp_path / "cards")  # elsewhere: links reach it
    runs_link = written[0].read_text().split("[its run folder](")[1].split(")")[0]
    assert (written[0].parent / runs_link).resolve() == entries[0].folder.resolve()
    card = (committed / "pick-her-cs-s1.md").read_text()
    for fact in ("| commit | c2a3187 |", "family 6 model 167", "0.80 (16/20, 95 % interval",
                 "hercs eval zoo:pick-her-cs-s1", "](../runs/pick-her-cs-s1/config.yaml)",
                 "hercs up --task pick --method her-cs --seed 1 --epochs 100"):
        assert fact in card, fact


@pytest.mark.parametrize("name", SHIPPED)
def test_a_cards_reproduce_command_resolves_to_the_runs_config(name: str, tmp_path: Path,
                                                                monkeypatch) -> None:
    monkeypatch.chdir(REPO)
    out = tmp_path / "resolved.yaml"
    assert main(["config", "--config", f"docs/results/runs/{name}/config.yaml", "--run", name,
                 "--run-dir", str(tmp_path / "runs"), "--listen", "tcp/127.0.0.1:0",
                 "-o", str(out)]) == 0
    from hercs.config import load_yaml

    again, shipped = load_yaml(out), load_yaml(REPO / f"docs/results/runs/{name}/config.yaml")
    assert (again.task, again.run.method, again.run.seed, again.training, again.ddpg) == (
        shipped.task, shipped.run.method, shipped.run.seed, shipped.training, shipped.ddpg)


def test_zoo_names_resolve_and_a_wrong_one_says_the_closest(capsys) -> None:
    assert zoo.zoo_folder("zoo:pick-her-cs-s1") == REPO / "docs/results/runs/pick-her-cs-s1"
    with pytest.raises(zoo.ZooError, match=r"did you mean .*zoo:pick-her-cs-s1"):
        zoo.zoo_folder("zoo:pick-her-cs")
    with pytest.raises(zoo.ZooError, match="no shipped policy"):
        zoo.zoo_folder("zoo:../runs")
    assert main(["eval", "zoo:nothing-here"]) == 2
    assert "hercs eval: zoo:nothing-here: no shipped policy" in capsys.readouterr().err


def test_the_wilson_interval() -> None:
    assert wilson_interval(16, 20) == pytest.approx((0.584, 0.919), abs=1e-3)
    assert wilson_interval(20, 20) == pytest.approx((0.839, 1.0), abs=1e-3)
    assert wilson_interval(0, 20)[0] == 0.0


RECORDED = RecordedSuccess(epoch=78, successes=16, episodes=20, mean_final_distance=0.0636,
                           evaluated_epochs=100)


def _outcomes(successes: int, distance: float, n: int = 20) -> list[tuple[bool, float]]:
    return [(i < successes, distance) for i in range(n)]


def test_eval_says_it_reproduced_the_recorded_episodes() -> None:
    said = comparison(RECORDED, _outcomes(16, 0.0636, 30), seed=None, from_best=True)
    assert said.startswith("metrics.csv recorded 0.80 (16/20, 95 % interval 0.58-0.92) at "
                           "epoch 78, the best of its 100 evaluated epochs")
    assert "give the same success and final distance; the 10 after them" in said


def test_eval_says_when_the_episodes_part_in_their_last_digits_on_another_cpu() -> None:
    said = comparison(RECORDED, _outcomes(16, 0.06363), seed=None, from_best=True,
                      run_cpu="Some Other CPU")
    assert "the same success, the mean final distance 3.0e-05 m from the recorded" in said
    assert "the run finished on Some Other CPU; this machine is" in said


def test_eval_says_why_an_outcome_differs_from_the_recorded_one() -> None:
    said = comparison(RECORDED, _outcomes(14, 0.08), seed=None, from_best=False)
    assert "give 0.70 and final distance 0.0800 m against 0.80 and 0.0636 m" in said
    assert "not the recorded outcome. Either its evaluator drew other goals" in said
    assert "best of" not in said, "a latest or epoch-N checkpoint was not chosen as the best"


def test_eval_on_other_goals_or_fewer_episodes_says_so() -> None:
    assert "other goals (--seed 7): an estimate of their own" in comparison(
        RECORDED, _outcomes(11, 0.1, 25), seed=7, from_best=True)
    assert "these 5 episodes are the first of its 20 (--episodes 20" in comparison(
        RECORDED, _outcomes(5, 0.1, 5), seed=None, from_best=True)
