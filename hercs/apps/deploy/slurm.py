"""`hercs slurm submit`: one run as one heterogeneous Slurm job (docs/CLUSTER.md).

Writes the job script into the run directory (`runs/<run>/slurm/job.sbatch`, to read, edit or
submit by hand) and calls `sbatch`: component 0 runs `hercs up --actors 0`, component 1 one
`hercs actor` per node, which finds the router through `router.json`. Each attempt makes its
own certificates, and an actor step that ends while the run goes on is started again within
it. Near the time limit the run stops in order and the job is requeued; its next attempt
continues with `hercs up --resume`, so a run may outlast any one job. The run itself is
`hercs up` and `hercs actor` as on any machine: this module only writes text and calls sbatch.
"""

from __future__ import annotations

import argparse
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.errors import ConfigError
from hercs.roles import SERVICE_ROLES
from hercs.run.rundir import CONFIG, SLURM, RunDir, holds_a_run

ACTOR_RESTART_S = 2
"""Seconds between an actor step's end and its restart within the attempt; doubled, up to
`ACTOR_RESTART_MAX_S`, while restarted steps keep failing fast."""
ACTOR_RESTART_MAX_S = 60

BESIDE_THE_LEARNER = ", ".join(r.name for r in SERVICE_ROLES.values() if not r.actor_node)
"""Component 0's roles (hercs/roles.py; the live view only with `view.live`)."""
ON_ACTOR_NODES = ", ".join(r.name for r in SERVICE_ROLES.values() if r.actor_node)
"""Component 1's: one process a node."""
SCRIPT = "job.sbatch"
TIME = re.compile(r"^(\d+-)?\d+(:\d{1,2}){0,2}$")
"""Slurm's --time forms: M, M:S, H:M:S, D-H, D-H:M, D-H:M:S."""
EXIT_REQUEUED = 0
"""The batch script's status after it requeued its job (Slurm starts it again)."""


@dataclass(frozen=True, kw_only=True)
class JobOptions:
    """What a run's job and a job array (`ArrayPlan`) both ask of Slurm beyond their
    resources: limits, the warning before the time limit on which they requeue, and more."""

    time: str = ""
    signal_before_s: int = 300
    partition: str = ""
    account: str = ""
    sbatch: tuple[str, ...] = ()
    """More sbatch options for the whole job (each becomes a `#SBATCH` line)."""
    workdir: Path = Path(".")
    """The job's working directory (`--chdir`; `plan_from_args` gives the submitting
    shell's)."""

    def sbatch_options(self, name: str, output: str, *resources: str) -> list[str]:
        """The script's `#SBATCH` options: the job's name and output file, appending and
        requeueing on the warning, its folder, then `resources`, then the rest of these."""
        options = [f"--job-name={name}", f"--output={output}", "--open-mode=append",
                   "--requeue", f"--signal=B:USR1@{self.signal_before_s}",
                   f"--chdir={self.workdir}", *resources]
        options += [f"--time={self.time}"] if self.time else []
        options += [f"--partition={self.partition}"] if self.partition else []
        options += [f"--account={self.account}"] if self.account else []
        return options + list(self.sbatch)


@dataclass(frozen=True)
class JobPlan(JobOptions):
    """What the job asks of Slurm and where the run lives."""

    run: str
    run_dir: Path
    """The run's folder (absolute, on storage every node shares)."""
    hercs: tuple[str, ...]
    """The command that runs `hercs` on the nodes."""
    actor_nodes: int = 1
    actor_cpus: int = 8
    learner_cpus: int = 4
    gpus: int = 0

    def __post_init__(self) -> None:
        for flag, value, least in (("--actor-nodes", self.actor_nodes, 1),
                                   ("--actor-cpus", self.actor_cpus, 1),
                                   ("--learner-cpus", self.learner_cpus, 1),
                                   ("--gpus", self.gpus, 0),
                                   ("--signal-before", self.signal_before_s, 10)):
            if value < least:
                raise ConfigError(f"{flag}: got {value}, must be >= {least}")
        if self.time and TIME.fullmatch(self.time) is None:
            raise ConfigError(f"--time: got {self.time!r}, must be a Slurm time limit: "
                              "MINUTES, H:MM:SS or D-HH:MM:SS")
        for option in self.sbatch:
            if not option.startswith("--") or "\n" in option:
                raise ConfigError(f"--sbatch: got {option!r}, must be one long sbatch option "
                                  "such as --qos=high")

    @property
    def folder(self) -> Path:
        return RunDir(self.run_dir).slurm


def render_script(plan: JobPlan) -> str:
    """The batch script of `plan` (see the module docstring)."""
    q = shlex.quote
    run_dir, parent, run = q(str(plan.run_dir)), q(str(plan.run_dir.parent)), q(plan.run)
    hercs = " ".join(q(part) for part in plan.hercs)
    whole = plan.sbatch_options(f"hercs-{plan.run}", f"{plan.folder}/job-%j.out")
    learner = ["--nodes=1", "--ntasks=1", f"--cpus-per-task={plan.learner_cpus}"]
    learner += [f"--gres=gpu:{plan.gpus}"] if plan.gpus else []
    actors = [f"--nodes={plan.actor_nodes}", "--ntasks-per-node=1",
              f"--cpus-per-task={plan.actor_cpus}"]
    head = "\n".join(f"#SBATCH {option}" for option in whole)
    return f"""#!/bin/bash
# hercs run {plan.run} as one heterogeneous Slurm job, written by `hercs slurm submit`
# (docs/CLUSTER.md). Edit it and submit it again with: sbatch {plan.folder / SCRIPT}
#   component 0: router, {BESIDE_THE_LEARNER} (`hercs up --actors 0`)
#   component 1: one {ON_ACTOR_NODES} per node, {plan.actor_cpus} envs each, over mutual TLS
# Slurm warns {plan.signal_before_s} s before the time limit: the run stops in order and the
# job requeues itself; the next attempt resumes the run (`hercs up --resume`).
{head}
# component 0
{chr(10).join(f"#SBATCH {option}" for option in learner)}
#SBATCH hetjob
# component 1
{chr(10).join(f"#SBATCH {option}" for option in actors)}

set -u
RUN_DIR={run_dir}
HERCS=({hercs})
ATTEMPT="$SLURM_JOB_ID.${{SLURM_RESTART_COUNT:-0}}"
CERTS="$RUN_DIR/{SLURM}/certs-$ATTEMPT"
log() {{ echo "[$(date +%FT%T)] job $ATTEMPT: $*"; }}

# USR1: Slurm's warning before the time limit (it may come up to a minute early); TERM:
# preemption, requeue or scancel. SIGTERM goes to the steps' tasks through Slurm (srun itself
# would end its step at once): `hercs up` stops in order, the actors leave.
REASON="" UP="" ACTORS=""
stop_run() {{
    REASON=$1
    log "got SIG$1, stopping the run in order"
    if [ -n "$UP" ]; then scancel --signal=TERM "$SLURM_JOB_ID"; fi
}}
trap 'stop_run USR1' USR1
trap 'stop_run TERM' TERM

# This attempt's certificates: the router's names this host, where component 0 runs.
# An earlier attempt's router.json names a router that is gone.
rm -f "$RUN_DIR/router.json"
"${{HERCS[@]}}" certs "$CERTS" --host "$(hostname)" > /dev/null || exit 1
rm -f "$CERTS/ca.key"

if [ -f "$RUN_DIR/config.yaml" ]; then
    log "continuing run {run} (hercs up --resume)"
    START=(--resume "$RUN_DIR")
else
    log "starting run {run}"
    START=(--config "$RUN_DIR/{SLURM}/{CONFIG}")
fi
# The actors' step, started again within this attempt whenever it ends while the run goes on
# (an actor killed or crashed; --kill-on-bad-exit ends the whole step when one node's actor
# dies, so that it is restarted at all): the run's only source of episodes must not wait for
# the next attempt. It ends for good when the actors exit 0 (the run finished: they stop by
# themselves), when one exits 2 (a configuration it would refuse again), or when this script
# stops it (TERM). The wait before a restart doubles from {ACTOR_RESTART_S} s up to
# {ACTOR_RESTART_MAX_S} s while steps keep failing fast, and starts over after a step that ran
# {ACTOR_RESTART_MAX_S} s.
actor_steps() {{
    local step="" code=0 stopping="" pause={ACTOR_RESTART_S} started
    trap 'stopping=1; [ -n "$step" ] && kill -TERM "$step" 2> /dev/null' TERM
    while [ -z "$stopping" ]; do
        started=$SECONDS
        srun --het-group=1 --ntasks-per-node=1 --kill-on-bad-exit=1 "${{HERCS[@]}}" actor \\
            --run {run} --run-dir {parent} --tls-dir "$CERTS" &
        step=$!
        [ -n "$stopping" ] && kill -TERM "$step" 2> /dev/null  # TERM came as it started
        wait "$step"; code=$?
        while kill -0 "$step" 2> /dev/null; do wait "$step"; code=$?; done  # a trap ran
        step=""
        if [ -n "$stopping" ] || [ "$code" -eq 0 ]; then break; fi
        if [ "$code" -eq 2 ]; then
            log "the actor step refused its configuration (status 2); not starting it again"
            break
        fi
        if [ $((SECONDS - started)) -ge {ACTOR_RESTART_MAX_S} ]; then pause={ACTOR_RESTART_S}; fi
        log "the actor step ended with status $code while the run goes on;" \\
            "starting it again in $pause s"
        sleep "$pause" & wait $! || true
        pause=$((pause * 2 > {ACTOR_RESTART_MAX_S} ? {ACTOR_RESTART_MAX_S} : pause * 2))
    done
}}

STATUS=1
if [ -z "$REASON" ]; then
    srun --het-group=0 --ntasks=1 "${{HERCS[@]}}" up "${{START[@]}}" --actors 0 \\
        --listen tls/0.0.0.0:0 --tls-dir "$CERTS" &
    UP=$!
    actor_steps &
    ACTORS=$!
    if [ -n "$REASON" ]; then scancel --signal=TERM "$SLURM_JOB_ID"; fi
    wait "$UP"; STATUS=$?
    while kill -0 "$UP" 2> /dev/null; do wait "$UP"; STATUS=$?; done  # a trap ended the wait
    kill -TERM "$ACTORS" 2> /dev/null  # the run is over: its actors have nothing to send
    wait "$ACTORS"
    while kill -0 "$ACTORS" 2> /dev/null; do wait "$ACTORS"; done
    log "hercs up exited with status $STATUS"
fi
if [ "$STATUS" -ne 0 ] && [ "$REASON" = USR1 ]; then
    log "requeueing: the next attempt continues the run"
    scontrol requeue "$SLURM_JOB_ID"
    exit {EXIT_REQUEUED}
fi
exit "$STATUS"
"""


def write_job(config: HercsConfig, plan: JobPlan) -> Path:
    """Write `slurm/config.yaml` and `slurm/job.sbatch` into the run's folder; returns the
    script's path. Refuses a folder that already holds a run."""
    if holds_a_run(plan.run_dir):
        raise ConfigError(f"{plan.run_dir} already holds a run; pick another --run (or "
                          f"submit its script again: sbatch {plan.folder / SCRIPT})")
    plan.folder.mkdir(parents=True, exist_ok=True)
    save_yaml(config, RunDir(plan.folder).config)
    script = plan.folder / SCRIPT
    script.write_text(render_script(plan))
    return script


def submit(script: Path) -> str:
    """`sbatch --parsable script`; returns the job id."""
    try:
        done = subprocess.run(["sbatch", "--parsable", str(script)], capture_output=True,
                              text=True, timeout=60)
    except FileNotFoundError:
        raise ConfigError("sbatch not found: run `hercs slurm submit` on a host of a Slurm "
                          f"cluster (the script is written: {script})") from None
    if done.returncode != 0:
        raise ConfigError(f"sbatch {script} failed (exit {done.returncode}): "
                          f"{done.stderr.strip()}")
    return done.stdout.strip().split(";")[0]


def plan_from_args(args: argparse.Namespace, config: HercsConfig) -> tuple[HercsConfig, JobPlan]:
    """The run's config (named, absolute run_dir, no local actors, the actor nodes' cores as
    envs per process) and the job's plan, from `hercs slurm submit`'s flags."""
    from hercs.apps.launch.run_plan import default_run_name

    name = config.run.name or default_run_name(config)
    parent = Path(config.run.run_dir).absolute()
    config = apply_overrides(config, [f"run.name={name}", f"run.run_dir={parent}",
                                      "actor.num_actors=0",
                                      f"actor.envs_per_process={args.actor_cpus}"])
    plan = JobPlan(run=name, run_dir=parent / name,
                   hercs=tuple(args.hercs.split()) if args.hercs else
                   (sys.executable, "-m", "hercs.apps.cli"),
                   actor_nodes=args.actor_nodes, actor_cpus=args.actor_cpus,
                   learner_cpus=args.learner_cpus, gpus=args.gpus, time=args.time,
                   signal_before_s=args.signal_before, partition=args.partition,
                   account=args.account, sbatch=tuple(args.sbatch),
                   workdir=Path.cwd())
    return config, plan


def add_sbatch_arguments(group: argparse._ArgumentGroup, *, prefix: str, scope: str) -> None:
    """The sbatch options `hercs slurm submit` (for the job) and `hercs sweep --slurm` (for
    each array task, `prefix` "slurm-") share: `--time`, `--signal-before`, `--partition`,
    `--account` and `--sbatch`, each named `--<prefix><name>`; `scope` is what they apply to."""
    group.add_argument(f"--{prefix}time", default="", metavar="LIMIT",
                       help=f"{scope}'s time limit (sbatch --time); a longer run requeues and "
                            "resumes")
    group.add_argument(f"--{prefix}signal-before", type=int, default=300, metavar="S",
                       help="seconds before the time limit at which the run stops in order and "
                            "requeues (default 300)")
    group.add_argument(f"--{prefix}partition", default="", help="sbatch --partition")
    group.add_argument(f"--{prefix}account", default="", help="sbatch --account")
    group.add_argument(f"--{prefix}sbatch", action="append", default=[], metavar="OPTION",
                       help=f"one more sbatch option for {scope}, e.g. "
                            f"--{prefix}sbatch=--qos=high (repeatable)")


def add_submit_arguments(parser: argparse.ArgumentParser) -> None:
    job = parser.add_argument_group("Slurm job")
    job.add_argument("--actor-nodes", type=int, default=1, metavar="N",
                     help="nodes of component 1, one actor process each (default 1)")
    job.add_argument("--actor-cpus", type=int, default=8, metavar="C",
                     help="CPUs per actor node, = the envs each actor steps "
                          "(actor.envs_per_process; default 8)")
    job.add_argument("--learner-cpus", type=int, default=4, metavar="C",
                     help="CPUs of component 0 (router, replay, clusterer, learner, "
                          "evaluator; default 4)")
    job.add_argument("--gpus", type=int, default=0, metavar="G",
                     help="GPUs for component 0's learner (--gres=gpu:G; default none)")
    add_sbatch_arguments(job, prefix="", scope="the job")
    job.add_argument("--hercs", metavar="COMMAND",
                     help="how the nodes run hercs (default: this Python, -m hercs.apps.cli)")
    job.add_argument("--dry-run", action="store_true",
                     help="print the batch script; write and submit nothing")


def run_submit(args: argparse.Namespace, config: HercsConfig) -> int:
    try:
        config, plan = plan_from_args(args, config)
        if args.dry_run:
            print(render_script(plan), end="")
            return 0
        script = write_job(config, plan)
        job = submit(script)
    except ConfigError as exc:
        print(f"hercs slurm submit: {exc}", file=sys.stderr)
        return 2
    print(f"hercs slurm submit: job {job} runs {plan.run}; script {script}; output "
          f"{plan.folder}/job-{job}.out; watch it with `hercs live --run {plan.run} --run-dir "
          f"{plan.run_dir.parent}`")
    return 0


# ------------------------------------------------------------------------------ job arrays

ARRAY_SCRIPT = "grid.sbatch"


@dataclass(frozen=True)
class ArrayPlan(JobOptions):
    """A job array whose task i runs `command i` (i = `$SLURM_ARRAY_TASK_ID`) on one node,
    requeueing itself on Slurm's warning before the time limit (the command must stop in
    order on SIGTERM and continue where it stopped when started again)."""

    name: str
    folder: Path
    """Where the script and the tasks' output go."""
    command: tuple[str, ...]
    indices: tuple[int, ...]
    cpus: int = 4

    def __post_init__(self) -> None:
        if not self.indices:
            raise ConfigError("a job array needs at least one task")
        # the resources are checked as a run's job checks them
        JobPlan(run=self.name, run_dir=self.folder, hercs=(), learner_cpus=self.cpus,
                time=self.time, signal_before_s=self.signal_before_s, sbatch=self.sbatch)


def render_array_script(plan: ArrayPlan) -> str:
    options = plan.sbatch_options(plan.name, f"{plan.folder}/task-%A_%a.out",
                                  f"--array={','.join(map(str, plan.indices))}", "--nodes=1",
                                  "--ntasks=1", f"--cpus-per-task={plan.cpus}")
    head = "\n".join(f"#SBATCH {option}" for option in options)
    command = " ".join(shlex.quote(part) for part in plan.command)
    return f"""#!/bin/bash
# {plan.name}: one array task per index, written by hercs (docs/CLUSTER.md). Task i runs the
# command below with SLURM_ARRAY_TASK_ID=i; Slurm's warning {plan.signal_before_s} s before the
# time limit stops it in order and requeues the task, which then continues where it stopped.
{head}

set -u
TASK="${{SLURM_ARRAY_JOB_ID}}_${{SLURM_ARRAY_TASK_ID}}"
log() {{ echo "[$(date +%FT%T)] task $TASK.${{SLURM_RESTART_COUNT:-0}}: $*"; }}
REASON="" PID=""
stop_task() {{
    REASON=$1
    log "got SIG$1, stopping in order"
    if [ -n "$PID" ]; then kill -TERM "$PID" 2> /dev/null; fi
}}
trap 'stop_task USR1' USR1
trap 'stop_task TERM' TERM

STATUS=1
if [ -z "$REASON" ]; then
    {command} "$SLURM_ARRAY_TASK_ID" &
    PID=$!
    wait "$PID"; STATUS=$?
    while kill -0 "$PID" 2> /dev/null; do wait "$PID"; STATUS=$?; done  # a trap ended the wait
    log "exited with status $STATUS"
fi
if [ "$STATUS" -ne 0 ] && [ "$REASON" = USR1 ]; then
    log "requeueing: the next attempt continues"
    scontrol requeue "$TASK"
    exit {EXIT_REQUEUED}
fi
exit "$STATUS"
"""


def submit_array(plan: ArrayPlan, *, dry_run: bool = False) -> tuple[Path, str | None]:
    """Write `folder/grid.sbatch` and submit it (not with `dry_run`); (script, job id)."""
    plan.folder.mkdir(parents=True, exist_ok=True)
    script = plan.folder / ARRAY_SCRIPT
    script.write_text(render_array_script(plan))
    return script, None if dry_run else submit(script)
