"""`hercs slurm submit --dry-run` and the job array's script, without a Slurm: what the
scripts ask of Slurm, that bash parses them, and flags refused with their name and value.
The scripts run for real in tests/integration/test_slurm.py."""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

from hercs.apps.cli.main import main
from hercs.apps.deploy.slurm import ArrayPlan, JobPlan, render_array_script, render_script
from hercs.errors import ConfigError
from hercs.run.rundir import RunDir


def sbatch_lines(script: str) -> list[str]:
    return [line.removeprefix("#SBATCH ") for line in script.splitlines()
            if line.startswith("#SBATCH ")]


def test_dry_run_prints_a_heterogeneous_job_and_writes_nothing(tmp_path: Path, capsys) -> None:
    assert main(["slurm", "submit", "--task", "push", "--run", "r1", "--run-dir",
                 str(tmp_path), "--actor-nodes", "4", "--actor-cpus", "8", "--gpus", "1",
                 "--time", "2:00:00", "--signal-before", "120", "--partition", "gpu",
                 "--sbatch=--qos=high", "--dry-run"]) == 0
    script = capsys.readouterr().out
    options = sbatch_lines(script)
    het = options.index("hetjob")
    assert options[:het] == [
        "--job-name=hercs-r1", f"--output={tmp_path}/r1/slurm/job-%j.out", "--open-mode=append",
        "--requeue", "--signal=B:USR1@120", f"--chdir={Path.cwd()}", "--time=2:00:00",
        "--partition=gpu", "--qos=high", "--nodes=1", "--ntasks=1", "--cpus-per-task=4",
        "--gres=gpu:1"]
    assert options[het + 1:] == ["--nodes=4", "--ntasks-per-node=1", "--cpus-per-task=8"]
    assert re.search(r"srun --het-group=0 .* up .* --actors 0 \\\n\s+--listen tls/0\.0\.0\.0:0",
                     script)
    assert f"actor \\\n            --run r1 --run-dir {tmp_path}" in script
    assert "srun --het-group=1 --ntasks-per-node=1 --kill-on-bad-exit=1" in script
    # the actors' step runs in a loop that starts it again while the run goes on
    assert re.search(r"actor_steps\(\) \{\n(.*\n)*\s+srun --het-group=1 (.*\n)*.*starting "
                     r"it again", script)
    assert "    actor_steps &\n    ACTORS=$!" in script
    assert not (tmp_path / "r1").exists()


def test_submit_writes_the_runs_config_for_its_first_attempt(tmp_path: Path) -> None:
    from hercs.apps.cli.main import build_parser, resolve_config
    from hercs.apps.deploy.slurm import plan_from_args, write_job
    from hercs.config import load_yaml

    args = build_parser()[0].parse_args(["slurm", "submit", "--task", "reach", "--run", "r2",
                                         "--run-dir", str(tmp_path), "--actor-cpus", "6",
                                         "--set", "ddpg.polyak=0.9"])
    config, plan = plan_from_args(args, resolve_config(args))
    script = write_job(config, plan)
    saved = load_yaml(RunDir(tmp_path / "r2").slurm / "config.yaml")
    assert (saved.run.name, saved.run.run_dir, saved.ddpg.polyak) == ("r2", str(tmp_path), 0.9)
    assert (saved.actor.num_actors, saved.actor.envs_per_process) == (0, 6)
    assert script == RunDir(tmp_path / "r2").slurm / "job.sbatch"
    RunDir(tmp_path / "r2").metrics.write_text("epoch\n1\n")
    with pytest.raises(ConfigError, match="already holds a run"):
        write_job(config, plan)


@pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")
def test_both_scripts_parse_as_bash(tmp_path: Path) -> None:
    job = render_script(JobPlan(run="r 3", run_dir=tmp_path / "r 3", hercs=("hercs",),
                                time="10"))
    array = render_array_script(ArrayPlan(name="g", folder=tmp_path, command=("echo", "a b"),
                                          indices=(0, 2, 5), time="1-00:00:00"))
    assert "#SBATCH --array=0,2,5" in array
    assert "echo 'a b' \"$SLURM_ARRAY_TASK_ID\" &" in array
    for name, text in (("job", job), ("array", array)):
        path = tmp_path / f"{name}.sh"
        path.write_text(text)
        done = subprocess.run(["bash", "-n", str(path)], capture_output=True, text=True)
        assert done.returncode == 0, f"{name}: {done.stderr}"


@pytest.mark.parametrize(("flags", "message"), [
    (["--actor-nodes", "0"], "--actor-nodes: got 0, must be >= 1"),
    (["--signal-before", "5"], "--signal-before: got 5, must be >= 10"),
    (["--time", "2h"], "--time: got '2h', must be a Slurm time limit"),
    (["--sbatch=qos=high"], "--sbatch: got 'qos=high', must be one long sbatch option"),
], ids=["actor-nodes", "signal-before", "time", "sbatch"])
def test_bad_job_flags_name_the_flag_and_value(flags: list[str], message: str,
                                               capsys) -> None:
    assert main(["slurm", "submit", "--dry-run", *flags]) == 2
    assert message in capsys.readouterr().err


def _actor_steps_shell(tmp_path: Path, exits: list[int], *, srun_sleeps_s: float = 0.0) -> Path:
    """The job script's `actor_steps` function with a fake `srun` whose steps end with
    `exits` in turn (after sleeping `srun_sleeps_s`), and `log` printing to stdout."""
    script = render_script(JobPlan(run="r", run_dir=tmp_path / "r", hercs=("hercs",)))
    function = re.search(r"^actor_steps\(\) \{\n.*?^\}\n", script, re.S | re.M)
    assert function is not None
    codes = tmp_path / "codes"
    codes.write_text("".join(f"{c}\n" for c in exits))
    path = tmp_path / "steps.sh"
    path.write_text(f"""set -u
HERCS=(hercs) CERTS=c
log() {{ echo "LOG $*"; }}
srun() {{
    echo "SRUN $*"
    code=$(head -n 1 {codes}); sed -i 1d {codes}
    # like srun, end the task on TERM: a shell function's `&` is a subshell, and a TERM
    # that killed it in a foreground `sleep` would leave the sleep holding stdout
    local task=""
    trap '[ -n "$task" ] && kill -TERM "$task" 2> /dev/null; exit 143' TERM
    sleep {srun_sleeps_s} > /dev/null & task=$!
    wait "$task"
    return "$code"
}}
{function.group(0)}
actor_steps
echo "ENDED"
""")
    return path


@pytest.mark.parametrize(("exits", "starts", "said"), [
    ([0], 1, []),
    ([137, 0], 2, ["ended with status 137"]),
    ([9, 2], 2, ["ended with status 9", "refused its configuration (status 2)"]),
], ids=["run-finished", "killed-then-finished", "killed-then-refused"])
def test_the_actor_step_is_started_again_until_it_exits_0_or_2(
        tmp_path: Path, exits: list[int], starts: int, said: list[str]) -> None:
    done = subprocess.run(["bash", str(_actor_steps_shell(tmp_path, exits))],
                          capture_output=True, text=True, timeout=60)
    out = done.stdout
    assert done.returncode == 0 and out.endswith("ENDED\n"), done.stderr
    assert out.count("SRUN --het-group=1") == starts
    logged = [line for line in out.splitlines() if line.startswith("LOG")]
    assert len(logged) == len(said) and all(
        line.startswith(f"LOG the actor step {s}") for line, s in zip(logged, said, strict=True))


def test_term_ends_the_actor_steps_at_once_with_the_step_in_flight(tmp_path: Path) -> None:
    proc = subprocess.Popen(["bash", str(_actor_steps_shell(tmp_path, [0], srun_sleeps_s=60))],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().startswith("SRUN")
    proc.send_signal(signal.SIGTERM)  # the parent script's `kill -TERM "$ACTORS"`
    out, _ = proc.communicate(timeout=30)
    assert out.endswith("ENDED\n") and "LOG" not in out
