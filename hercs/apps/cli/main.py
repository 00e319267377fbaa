"""The `hercs` command line. Every command resolves one `HercsConfig` the same way:
defaults (docs/DESIGN.md §4) ← `--config FILE.yaml` ← shortcut flags (`--task`, `--method`, …) ←
`--set section.field=value` (repeatable). Bad values exit with status 2 and a message naming
the field.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import yaml

from hercs.apps.cli.config_flags import (
    JOINERS,
    add_config_arguments,
    add_rerun_arguments,
    add_trust_argument,
    join_endpoints,
    resolve_config,
    trust_named_tasks,
)
from hercs.apps.cli.services import Command, exit_after_close, service_command
from hercs.apps.output_paths import OutputPathError, check_outputs
from hercs.apps.plots.curves import BANDS, DEFAULT_BAND
from hercs.apps.tracking.flags import add_track_argument
from hercs.config import HercsConfig
from hercs.errors import ConfigError, HercsError
from hercs.roles import SERVICE_ROLES


def _cmd_config(args: argparse.Namespace, config: HercsConfig) -> int:
    text = yaml.safe_dump(config.to_dict(), sort_keys=False)
    if config.energy.epsilon is None:  # unset stays unset (a later env version picks it)
        text += (f"# energy.epsilon null: the simulator's, {config.energy_epsilon:g} with "
                 f"task.env_version {config.task.env_version} (docs/DESIGN.md §9.3)\n")
    if args.output:
        with open(args.output, "w") as f:
            f.write(text)
        print(f"wrote {args.output}")
    else:
        print(text, end="")
    return 0




def _cmd_up(args: argparse.Namespace, config: HercsConfig) -> int:
    from hercs.apps.launch.launcher import run_up

    return run_up(config, resume=bool(args.resume), restart=args.restart)


EXIT_NO_ROUTER = 3
"""A joiner gave up waiting for the run's router (as a service does, `transport.wait_s`)."""


def _cmd_slurm(args: argparse.Namespace, config: HercsConfig) -> int:
    from hercs.apps.deploy.slurm import run_submit

    return run_submit(args, config)


def _cmd_router(args: argparse.Namespace, config: HercsConfig) -> int:
    from hercs.apps.launch.router import run_router

    return run_router(config)


def _cmd_plot(args: argparse.Namespace) -> int:
    from hercs.apps.plots.command import run_plot
    from hercs.apps.plots.series import SeriesChoice
    from hercs.errors import HercsError
    from hercs.run.rundir import METRICS, require_run_dir

    try:
        for run_dir in args.run_dirs:  # what a folder lacks, before plots reads any
            require_run_dir(run_dir, needs=(METRICS,))
        return run_plot(args.run_dirs, args.output, reference=args.reference, table=args.table,
                        xmax=args.xmax, figure=args.figure, band=args.band,
                        choice=SeriesChoice(tuple(args.series), args.all_series))
    except HercsError as exc:
        print(f"hercs plot: {exc}", file=sys.stderr)
        return 2




def _cmd_sweep(args: argparse.Namespace) -> int:
    from hercs.apps.sweep.grid import main as sweep_main

    return sweep_main(args.sweep_args)


def _cmd_view(args: argparse.Namespace) -> int:
    from hercs.apps.views.view import run_view

    return run_view(args.path, save=args.save, episodes=args.episodes, web=args.web,
                    web_port=args.web_port, grpc_port=args.grpc_port, web_bind=args.web_bind,
                    open_browser=not args.no_browser)


class _PrintVersion(argparse.Action):
    """`hercs --version`, read when asked (a git call would slow every command's start)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS,
                 help: str | None = None) -> None:
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0,
                         help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        from hercs.apps.cli.version import version_text

        print(version_text())
        parser.exit()


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, Command]]:
    parser = argparse.ArgumentParser(
        prog="hercs",
        description="Hindsight Experience Replay with Cluster-based Sampling, as distributed "
                    "services over Eclipse Zenoh.",
    )
    parser.add_argument("--version", action=_PrintVersion,
                        help="print the version (and the git commit of a checkout) and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    commands: dict[str, Command] = {}

    p = sub.add_parser("config", help="print (or save) the fully resolved configuration")
    add_config_arguments(p, "config")
    add_rerun_arguments(p)
    p.add_argument("-o", "--output", metavar="FILE", help="write the YAML here instead")
    commands["config"] = _cmd_config

    p = sub.add_parser(
        "up", help="run everything on this machine: embedded router, replay, clusterer, "
                   "learner, evaluator and --actors actors; Ctrl-C stops the run",
        description="Start a whole run locally. The router is embedded and listens on --listen "
                    "(use tcp/0.0.0.0:PORT to let actors on other hosts join); the services "
                    "connect to it on this host. --rerun adds the "
                    "live view (hercs/apps/views/live_view.py), which training never waits "
                    "for. Example: "
                    "hercs up --task push --method her-cs --epochs 50 --seed 1",
    )
    add_config_arguments(p, "up")
    add_rerun_arguments(p)
    add_track_argument(p)
    p.add_argument("--tensorboard", action="store_true",
                   help="the same as --track tensorboard: event files in RUN/tensorboard/ "
                        "(view with `tensorboard --logdir runs/`)")
    p.add_argument("--resume", metavar="RUN_DIR",
                   help="continue the run in RUN_DIR (e.g. runs/push-her-cs-s1-…) where it "
                        "stopped: the replay reloads its log, the learner its checkpoint, the "
                        "clusterer asks the replay; metrics.csv goes on from the last epoch. "
                        "Refused (exit 2, nothing started) when that would lose results: no "
                        "checkpoint to continue from, or files that disagree; a finished run "
                        "says so and starts nothing")
    p.add_argument("--restart", action="store_true",
                   help="with --resume: start the run over from epoch 1 with its saved "
                        "config; what it made (metrics.csv, checkpoints/, the episode log) "
                        "is moved to RUN_DIR/previous/<time>/ first, never deleted")
    commands["up"] = _cmd_up

    p = sub.add_parser("slurm", help="run on a Slurm cluster (docs/CLUSTER.md)",
                       description="Slurm jobs of hercs runs (docs/CLUSTER.md).")
    slurm = p.add_subparsers(dest="slurm_command", metavar="SLURM_COMMAND", required=True)
    p = slurm.add_parser(
        "submit", help="submit one run as one heterogeneous job",
        description="Write runs/RUN/slurm/job.sbatch (component 0: `hercs up --actors 0` on "
                    "one node; component 1: one actor per node over mutual TLS; a warning "
                    "before the time limit stops the run in order and requeues the job, which "
                    "then resumes) and submit it. Example: hercs slurm submit --task push "
                    "--method her-cs --epochs 100 --actor-nodes 4 --actor-cpus 8 --gpus 1 "
                    "--time 2:00:00")
    add_config_arguments(p, "slurm")
    from hercs.apps.deploy.slurm import add_submit_arguments

    add_submit_arguments(p)
    commands["slurm"] = _cmd_slurm

    p = sub.add_parser("router", help="run a standalone Zenoh router (e.g. --listen "
                                      "tcp/0.0.0.0:7447) until Ctrl-C",
                       description="Route one or more runs' traffic; logs every hercs process "
                                   "that joins or leaves. Example: hercs router --tls-dir certs "
                                   "--listen tls/0.0.0.0:7447")
    add_config_arguments(p, "router")
    commands["router"] = _cmd_router

    for role in SERVICE_ROLES.values():
        name, help_text = role.name, role.summary
        p = sub.add_parser(name, help=help_text,
                           description=f"{help_text[0].upper()}{help_text[1:]}: one process of "
                                       "a run, what `hercs up` and docker-compose.yml start. "
                                       f"Example: {role.example}")
        add_config_arguments(p, name)
        if name == "live":
            add_rerun_arguments(p)
        p.add_argument("--id", dest="ident", help="process id (default: host name + short uuid)")
        commands[name] = service_command(role.module)

    p = sub.add_parser(
        "learner-stack", help="one learner process training several runs, their updates "
                              "stacked (runs started with launch.learner_elsewhere)",
        description="Trains each run to its end in this one process, all their DDPG updates "
                    "as one stacked update (each run keeps its weights, batches, checkpoints "
                    "and metrics; a run's checkpoint resumes with a lone learner too). Start "
                    "each run first with `hercs up ... --set launch.learner_elsewhere=true`. "
                    "Example: hercs learner-stack runs/push-her-s1 runs/push-her-s2")
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR",
                   help="the runs' folders (each holds the config.yaml its hercs up wrote)")
    p.add_argument("--id", dest="ident", help="process id (default: learner-stack)")

    p = sub.add_parser(
        "sweep", help="a grid of runs (tasks × methods × seeds × variants), resumable, locally "
                      "or as a Slurm job array; `hercs sweep report` its curves and claims table",
        description="hercs sweep [OPTIONS] runs the grid; hercs sweep report RUN_DIR writes "
                    "its report. `hercs sweep --help` lists the options.",
        add_help=False)
    p.add_argument("sweep_args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    p = sub.add_parser("plot", help="learning curves (PNG) and milestone tables of run folders",
                       description="10-epoch mean of the seed mean of the success rate per "
                                   "epoch, with a bootstrap 95 % interval band (and/or the "
                                   "min–max band), one panel per task, the legend beside it; "
                                   "milestone tables on stdout. Runs that differ by their seed "
                                   "alone are one series, labelled by what differs from the "
                                   "defaults (schedule, precision, lag T/P/Q/B, ε, env). A "
                                   "panel draws at most 6 series (the authors' included): "
                                   "those with the fewest settings changed, v1 next; stderr "
                                   "names the rest. A folder named twice is read once.")
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="run folders (config.yaml + "
                   "metrics.csv)")
    p.add_argument("-o", "--output", required=True, metavar="FIG.png", help="figure to write")
    p.add_argument("--reference", action="store_true",
                   help="overlay the authors' per-seed curves of the methods drawn (installed "
                        "with hercs: hercs/apps/plots/data/authors_success_rates.csv)")
    p.add_argument("--series", action="append", default=[], metavar="PATTERN",
                   help="draw the series whose key or label matches (shell-style, any case; "
                        "repeatable), instead of the default choice: '*lag*', 'her-cs/*', "
                        "'*lockstep*'")
    p.add_argument("--all-series", action="store_true",
                   help="draw every series, however many (the tables always list them all)")
    p.add_argument("--table", metavar="FILE.md", help="also write the tables here")
    p.add_argument("--xmax", type=int, metavar="EPOCH",
                   help="x axis end (default: the last epoch of our runs; 200 with --figure 2)")
    p.add_argument("--band", choices=BANDS, default=DEFAULT_BAND,
                   help="ci: bootstrap 95 %% interval of the seed mean (default); minmax: "
                        "min–max over seeds; both: the interval and, lighter, the min–max")
    p.add_argument("--figure", type=int, choices=[2],
                   help="the paper's figure layout: 2 = Fig. 2 (2x3 panels: HER vs HER-CS and "
                        "HER-EBP vs HER-EBP-CS on Push, PickAndPlace, Slide; authors dashed), "
                        "as docs/results/fig2.png is drawn")

    p = sub.add_parser("view", help="open (or --save) a Rerun recording of a run's episode log",
                       description="3D trajectories of gripper, object and goal per episode, "
                                   "success, clusters, failed goals, centroids and the learning "
                                   "curve (entity paths: see hercs/apps/views/view.py).")
    p.add_argument("path", metavar="PATH", help="episodes.mcap or a run directory")
    p.add_argument("--save", metavar="OUT.rrd", help="write an .rrd file instead of a viewer")
    p.add_argument("--episodes", metavar="SELECTION",
                   help="episode ids: '0:100', '5,7,9', '0:2000:10', 'last:20', "
                        "'spread:200' (every n-th, at most 200), 'all' (default: the last "
                        "epoch's episodes)")
    p.add_argument("--web", action="store_true",
                   help="serve the web viewer (http://127.0.0.1:9090, this machine only) "
                        "until Ctrl-C")
    p.add_argument("--web-port", type=int, metavar="PORT", help="web viewer's HTTP port "
                   "(9090)")
    p.add_argument("--grpc-port", type=int, metavar="PORT", help="with --web: the port the "
                   "recording is served on to the viewer (9876)")
    p.add_argument("--web-bind", metavar="ADDRESS",
                   help="with --web: the address both ports listen on (default 127.0.0.1: "
                        "this machine only). 0.0.0.0 or one of the host's addresses lets "
                        "others open the page, and anyone who reaches it sees the run's "
                        "episodes: there is no login (docs/SECURITY.md)")
    p.add_argument("--no-browser", action="store_true", help="with --web: do not open a browser")

    p = sub.add_parser("eval", help="evaluate a run's trained policy; record a video",
                       description="Loads a checkpoint (no service needed), runs deterministic "
                                   "episodes and reports success and final distance; --video "
                                   "records them (MuJoCo offscreen: EGL, else OSMesa). Example: "
                                   "hercs eval runs/RUN --video policy.mp4")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder (runs/RUN), or zoo:NAME "
                   "for a shipped policy (`hercs zoo` lists them)")
    p.add_argument("--checkpoint", metavar="NAME", help="best (default when kept), latest, "
                   "epoch-N, or a file")
    p.add_argument("--episodes", type=int, default=20, help="episodes to run (default 20)")
    p.add_argument("--seed", type=int, help="draw goals from this seed (default: the goals "
                   "the run's evaluator used for that epoch)")
    p.add_argument("--video", metavar="OUT.mp4", help="record the episodes (25 fps)")
    p.add_argument("--rerun-save", metavar="OUT.rrd", help="record the camera images in Rerun")
    p.add_argument("--task", metavar="TASK", help="the run's package.module:factory, where it "
                   "has one: hercs imports environment code only where you name it "
                   "(docs/SECURITY.md)")
    add_trust_argument(p)

    p = sub.add_parser("zoo", help="list the shipped policies (hercs eval zoo:NAME evaluates "
                                   "one)",
                       description="Every committed run that keeps its best policy "
                                   "(docs/results/runs/*/checkpoints/best.pt): its task, method, "
                                   "simulator, epoch, the success its run recorded there, and "
                                   "the commit and machine it came from.")
    p.add_argument("--markdown", action="store_true",
                   help="print the README's block (a table linking each model card) instead")
    p.add_argument("--cards", metavar="DIR", help="also write each policy's model card, "
                   "DIR/NAME.md (the committed ones: docs/results/zoo)")
    p.add_argument("--runs", metavar="DIR", help="the run folders to list (default: this "
                   "checkout's docs/results/runs)")

    p = sub.add_parser("certs", help="make a CA and the certificates of a secured run",
                       description="Writes DIR/ca.pem (+ ca.key), DIR/router.pem (+ .key) and "
                                   "DIR/<role>.pem (+ .key) for every role; then run "
                                   "`hercs up --tls-dir DIR --listen tls/0.0.0.0:7447`. See "
                                   "docs/SECURITY.md.")
    p.add_argument("out", metavar="DIR", help="folder to write into (files are never "
                   "overwritten)")
    p.add_argument("--host", dest="hosts", action="append", default=[], metavar="NAME",
                   help="a name or address clients use to reach the router (repeatable; "
                        "localhost and 127.0.0.1 are always included)")
    p.add_argument("--credentials", action="store_true",
                   help="also write credentials.txt: a random password per role")
    return parser, commands


def _cmd_learner_stack(args: argparse.Namespace) -> int:
    from hercs.learner.stacked_shell import run as run_stack

    try:
        code = run_stack([Path(d) for d in args.run_dirs], ident=args.ident)
    except ConfigError as exc:
        print(f"hercs learner-stack: {exc}", file=sys.stderr)
        return 2
    exit_after_close(code)


def _cmd_eval(args: argparse.Namespace) -> int:
    from hercs.apps.evaluation.policy_eval import run_eval

    trust_named_tasks(args)
    return run_eval(args.run_dir, checkpoint=args.checkpoint, episodes=args.episodes,
                    seed=args.seed, video=args.video, rerun_save=args.rerun_save)


def _cmd_zoo(args: argparse.Namespace) -> int:
    from hercs.apps.evaluation.zoo import run_zoo

    return run_zoo(runs=args.runs, as_markdown=args.markdown, cards=args.cards)


def _cmd_certs(args: argparse.Namespace) -> int:
    from hercs.apps.deploy.certs import run_certs

    try:
        return run_certs(args.out, hosts=args.hosts, credentials=args.credentials)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2


def _needs_extras(command: Callable[[argparse.Namespace], int]
                 ) -> Callable[[argparse.Namespace], int]:
    """A command whose optional libraries (rerun-sdk, matplotlib, imageio-ffmpeg) may be absent,
    as in the compose `services` image: say so instead of a traceback (exit 2)."""

    def run(args: argparse.Namespace) -> int:
        try:
            return command(args)
        except ModuleNotFoundError as exc:
            print(f"hercs {args.command}: needs the Python package {exc.name!r}, which this "
                  "installation lacks (the compose `services` image leaves out the viewers: "
                  "use the full image, `docker build -t hercs:full .`, or pip install it)",
                  file=sys.stderr)
            return 2

    return run


# Commands that read existing run directories or make files, and need no config.
NO_CONFIG_COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "plot": _needs_extras(_cmd_plot), "view": _needs_extras(_cmd_view), "certs": _cmd_certs,
    "eval": _needs_extras(_cmd_eval), "sweep": _needs_extras(_cmd_sweep), "zoo": _cmd_zoo,
    "learner-stack": _cmd_learner_stack}


ENV_COMMANDS = frozenset({"up", "actor", "evaluator"})
"""Commands that make envs, themselves or in their children: before anything starts they check
that the task's env can be made here (the v1 envs need `make mujoco-py`). A remote actor, which
learns its task from the run, meets a missing mujoco-py when it makes its envs instead."""


def _unknown_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace,
                       unknown: list[str]) -> int:
    """An unknown flag, told by the command it was given to (its usage, not the top-level
    one), with the closest flags that command takes; exit 2 as argparse's own errors."""
    import difflib

    command = getattr(args, "command", None)
    sub = _subparser(parser, command) if command else None
    target = sub or parser
    known = sorted({flag for action in target._actions for flag in action.option_strings})
    hints = []
    for word in unknown:
        if word.startswith("-"):
            close = difflib.get_close_matches(word.partition("=")[0], known, n=1, cutoff=0.7)
            if close:
                hints.append(f"{word}: did you mean {close[0]}?")
    target.print_usage(sys.stderr)
    print(f"{target.prog}: error: unrecognized arguments: {' '.join(unknown)}"
          + "".join(f"\n  {hint}" for hint in hints), file=sys.stderr)
    return 2


def _subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found = action.choices.get(name)
            if isinstance(found, argparse.ArgumentParser):
                return found
    return None


def main(argv: list[str] | None = None) -> int:
    parser, commands = build_parser()
    words = sys.argv[1:] if argv is None else argv
    if words[:1] == ["sweep"]:  # its own parser (and `sweep report`'s): options pass through
        return NO_CONFIG_COMMANDS["sweep"](argparse.Namespace(command="sweep",
                                                              sweep_args=list(words[1:])))
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        return _unknown_arguments(parser, args, unknown)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        check_outputs(args)
    except OutputPathError as exc:
        print(f"hercs {args.command}: {exc}", file=sys.stderr)
        return 2
    if args.command in NO_CONFIG_COMMANDS:
        return NO_CONFIG_COMMANDS[args.command](args)
    try:
        config = resolve_config(args)
    except ConfigError as exc:
        print(f"hercs {args.command}: invalid configuration: {exc}", file=sys.stderr)
        return 2
    if args.command in ENV_COMMANDS:
        from hercs.rl.envs import check_env

        try:
            check_env(config.task.spec)
        except ConfigError as exc:
            print(f"hercs {args.command}: {exc}", file=sys.stderr)
            return 2
    if args.command in JOINERS:
        try:
            joined = join_endpoints(args, config)
        except (ConfigError, HercsError) as exc:
            print(f"hercs {args.command}: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            return 128 + 2
        if joined is None:
            return EXIT_NO_ROUTER
        config = joined
    return commands[args.command](args, config)


if __name__ == "__main__":
    sys.exit(main())
