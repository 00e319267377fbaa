"""The `hercs` command line. Every command resolves one `HercsConfig` the same way:
defaults (docs/DESIGN.md §4) ← `--config FILE.yaml` ← shortcut flags (`--task`, `--method`, …) ←
`--set section.field=value` (repeatable). Bad values exit with status 2 and a message naming
the field.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import yaml

from apps.plots import BANDS, DEFAULT_BAND
from hercs.config import HercsConfig, apply_overrides, load_yaml, workers_overrides
from hercs.errors import ConfigError, HercsError
from hercs.methods import METHODS
from hercs.tasks import TASKS

# Shortcut flags and the config field each one sets.
SHORTCUTS: dict[str, str] = {
    "task": "task.name",
    "method": "run.method",
    "seed": "run.seed",
    "epochs": "training.epochs",
    "run": "run.name",
    "run_dir": "run.run_dir",
    "actors": "actor.num_actors",
}


RUN_FLAGS = ("task", "method", "seed", "epochs", "run", "run_dir", "actors", "workers")
"""The flags that shape a run; `FLAGS_OF` says which command takes which."""

FLAGS_OF: dict[str, tuple[str, ...]] = {
    "config": (*RUN_FLAGS, "connect", "listen", "security"),
    "up": (*RUN_FLAGS, "listen", "security"),
    # a Slurm job's run: its router, actors and certificates are the job script's
    "slurm": ("task", "method", "seed", "epochs", "run", "run_dir", "workers"),
    "router": ("listen", "security"),
    "replay": ("task", "method", "seed", "epochs", "run", "run_dir", "connect", "security"),
    # --workers shapes a run once, in the config `hercs up` saves: not a service flag
    "clusterer": ("task", "method", "seed", "epochs", "run", "run_dir", "connect",
                  "security"),
    "learner": ("task", "method", "seed", "epochs", "run", "run_dir", "connect", "security"),
    "evaluator": ("task", "method", "seed", "epochs", "run", "run_dir", "connect",
                  "security"),
    # actors and the live view take everything else from the run's replay; without
    # --connect they find the router in the run directory (`join_endpoints`)
    "actor": ("run", "run_dir", "connect", "security"),
    "live": ("run", "run_dir", "connect", "security"),
}
JOINERS = frozenset({"actor", "live"})
"""Commands that join a running run and, without --connect, read its router.json."""
EXIT_NO_ROUTER = 3
"""A joiner gave up waiting for the run's router (as a service does, `transport.wait_s`)."""


def add_config_arguments(parser: argparse.ArgumentParser, command: str) -> None:
    """--config and --set, plus the shortcuts `command` uses (`FLAGS_OF`)."""
    flags = FLAGS_OF[command]
    group = parser.add_argument_group("configuration")
    group.add_argument("--config", metavar="FILE", help="YAML config (partial is fine)")
    group.add_argument("--set", dest="overrides", action="append", default=[],
                       metavar="SECTION.FIELD=VALUE",
                       help="override any config field, e.g. --set ddpg.lr_actor=5e-4")
    helps = {
        "task": dict(choices=sorted(TASKS),
                     help="task preset (Fetch*-v4; --set task.env_version=v1: the authors' "
                          "Fetch*-v1)"),
        "method": dict(choices=list(METHODS), help="sampling method"),
        "seed": dict(type=int, help="root seed"),
        "epochs": dict(type=int, help="training epochs"),
        "run": dict(help="run name (Zenoh key prefix and folder name)"),
        "run_dir": dict(help="parent folder of run directories"),
        "actors": dict(type=int, help="rollout actors to start"),
        "workers": dict(type=int, metavar="N",
                        help="the reference's N-worker setting: N× episodes per cycle, N× "
                             "minibatch, N actors (docs/PERFORMANCE.md)"),
    }
    for flag in RUN_FLAGS:
        if flag in flags:
            group.add_argument(f"--{flag.replace('_', '-')}", **helps[flag])  # type: ignore[arg-type]
    if "connect" in flags:
        group.add_argument("--connect", action="append", metavar="ENDPOINT",
                           help="Zenoh endpoint to connect to, e.g. tcp/10.0.0.2:7447 "
                                "(repeatable)")
    if "listen" in flags:
        group.add_argument("--listen", action="append", metavar="ENDPOINT",
                           help="Zenoh endpoint for the router to listen on (repeatable)")
    if "security" in flags:
        add_security_arguments(parser)


def add_security_arguments(parser: argparse.ArgumentParser) -> None:
    sec = parser.add_argument_group(
        "security (docs/SECURITY.md; `hercs certs DIR` makes certificates)")
    sec.add_argument("--tls-dir", metavar="DIR", help="what `hercs certs DIR` made: "
                     "DIR/ca.pem, and DIR/<role>.pem + .key for each process (hercs up)")
    sec.add_argument("--tls-ca", metavar="CA.pem", help="the CA that signed every certificate "
                     "of the run (mutual TLS; endpoints become tls/HOST:PORT)")
    sec.add_argument("--tls-cert", metavar="CERT.pem", help="this process's certificate (the "
                     "router's, or a client's whose common name is its role)")
    sec.add_argument("--tls-key", metavar="KEY.pem", help="the private key of --tls-cert")
    sec.add_argument("--credentials", metavar="FILE", help="user:password lines (router: all "
                     "users; a client: its own line, user = its role)")


def add_rerun_arguments(parser: argparse.ArgumentParser) -> None:
    """The live view's options (`hercs up`, `hercs live`); they set the `view` section."""
    group = parser.add_argument_group("live view (Rerun)")
    group.add_argument("--rerun", nargs="?", const="spawn", metavar="URL",
                       help="stream metrics, episodes and clusters to Rerun while training "
                            "runs: without URL a local viewer is started (port 9876); with "
                            "URL (e.g. rerun+http://HOST:9876/proxy, or a port) a running "
                            "viewer is used")
    group.add_argument("--rerun-save", metavar="FILE.rrd",
                       help="write the live recording to this file (no viewer unless --rerun "
                            "is given too): for machines without a display")
    group.add_argument("--rerun-every", type=int, metavar="N",
                       help="draw the 3D trajectory of every N-th episode (default 20, 0 = "
                            "none)")


def rerun_overrides(args: argparse.Namespace) -> list[str]:
    """`view.*` overrides for --rerun / --rerun-save / --rerun-every (absent flags: none)."""
    viewer = getattr(args, "rerun", None)
    save = getattr(args, "rerun_save", None)
    every = getattr(args, "rerun_every", None)
    overrides = []
    if viewer is not None or save is not None:
        overrides.append("view.live=true")
        if viewer is not None and viewer.isdigit():  # a bare port: a viewer on this host
            viewer = f"rerun+http://127.0.0.1:{viewer}/proxy"
        overrides.append(f"view.viewer={viewer if viewer is not None else 'none'}")
    if save is not None:
        overrides.append(f"view.save={Path(save).absolute()}")
    if every is not None:
        overrides.append(f"view.episode_every={every}")
    return overrides


RESUME_FIXED = ("config", "task", "method", "seed", "run", "run_dir", "workers")
"""Flags `--resume` refuses: a resumed run keeps its saved config's task, method, seed and
name (what it may change: --epochs, --actors, --listen, --rerun…, --set)."""


def resume_config(args: argparse.Namespace) -> HercsConfig:
    """The saved config of the run folder `--resume` names, with run.name/run_dir set from
    the folder's path."""
    given = [f"--{flag.replace('_', '-')}" for flag in RESUME_FIXED
             if getattr(args, flag, None) is not None]
    if given:
        raise ConfigError(f"--resume continues a run with its saved config; {', '.join(given)} "
                          "cannot change it (--epochs, --actors, --listen and --set can)")
    run_dir = Path(args.resume)
    saved = run_dir / "config.yaml"
    if not saved.is_file():
        raise ConfigError(f"--resume {args.resume}: no config.yaml there; give the folder of a "
                          "run that `hercs up` started (runs/RUN)")
    config = load_yaml(saved)
    return apply_overrides(config, [f"run.name={run_dir.resolve().name}",
                                    f"run.run_dir={run_dir.resolve().parent}"])


def resolve_config(args: argparse.Namespace) -> HercsConfig:
    if getattr(args, "resume", None):
        config = resume_config(args)
    else:
        config = load_yaml(args.config) if args.config else HercsConfig()
    overrides = [f"{field}={getattr(args, flag)}" for flag, field in SHORTCUTS.items()
                 if getattr(args, flag, None) is not None]
    workers = getattr(args, "workers", None)
    if workers is not None:  # scales the file's and the shortcuts' values; --set still wins
        config = apply_overrides(config, overrides)
        overrides = workers_overrides(config, workers)
        if getattr(args, "actors", None) is not None:  # an explicit --actors wins
            overrides.append(f"actor.num_actors={args.actors}")
    if getattr(args, "tensorboard", False):
        overrides.append("run.tensorboard=true")
    tls_dir = getattr(args, "tls_dir", None)
    if tls_dir is not None:
        base = Path(tls_dir).absolute()
        overrides += [f"security.tls_ca={base / 'ca.pem'}",
                      f"security.tls_cert={base / '{role}.pem'}",
                      f"security.tls_key={base / '{role}.key'}"]
    for flag in ("tls_ca", "tls_cert", "tls_key", "credentials"):
        path = getattr(args, flag, None)
        if path is not None:  # absolute: children and a resumed run may start elsewhere
            overrides.append(f"security.{flag}={Path(path).absolute()}")
    for flag in ("connect", "listen"):
        endpoints = getattr(args, flag, None)
        if endpoints:
            listed = yaml.safe_dump(endpoints, default_flow_style=True).strip()
            overrides.append(f"transport.{flag}={listed}")
    return apply_overrides(config, overrides + rerun_overrides(args) + list(args.overrides))


def join_endpoints(args: argparse.Namespace, config: HercsConfig) -> HercsConfig | None:
    """An actor's or live view's config with `transport.connect` = the endpoints the run's
    `hercs up` recorded in RUN_DIR/RUN/router.json, when --connect is not given.

    With --run-dir given it waits for the file (`transport.wait_s`, 0 = for ever: a Slurm
    job's actors start with the run, before its router listens); None when it gave up.
    Without --run-dir it uses runs/RUN/router.json if there is one, else the config's
    `connect` as before."""
    from hercs.rundir import read_router, wait_router

    if getattr(args, "connect", None) or not config.run.name:
        if getattr(args, "run_dir", None) is not None and not config.run.name:
            raise ConfigError("--run-dir: give --run RUN too (the router is recorded in "
                              "RUN_DIR/RUN/router.json)")
        return config
    run_dir = Path(config.run.run_dir) / config.run.name
    if args.run_dir is None:
        record = read_router(run_dir)
    else:
        record = wait_router(run_dir, timeout_s=config.transport.wait_s,
                             say=lambda line: print(f"hercs {args.command}: {line}",
                                                    file=sys.stderr, flush=True))
        if record is None:
            print(f"hercs {args.command}: no router recorded in {run_dir} after "
                  f"{config.transport.wait_s:g} s (transport.wait_s); is the run's `hercs up` "
                  "running, and is RUN_DIR on storage this host shares with it?",
                  file=sys.stderr, flush=True)
            return None
    if record is None:
        return config
    listed = yaml.safe_dump(record.endpoints_for(), default_flow_style=True).strip()
    return apply_overrides(config, [f"transport.connect={listed}"])


def _cmd_config(args: argparse.Namespace, config: HercsConfig) -> int:
    text = yaml.safe_dump(config.to_dict(), sort_keys=False)
    if args.output:
        with open(args.output, "w") as f:
            f.write(text)
        print(f"wrote {args.output}")
    else:
        print(text, end="")
    return 0


Command = Callable[[argparse.Namespace, HercsConfig], int]


def _cmd_up(args: argparse.Namespace, config: HercsConfig) -> int:
    from apps.launcher import run_up

    return run_up(config, resume=bool(args.resume))


def _cmd_slurm(args: argparse.Namespace, config: HercsConfig) -> int:
    from apps.slurm import run_submit

    return run_submit(args, config)


def _cmd_router(args: argparse.Namespace, config: HercsConfig) -> int:
    from apps.router import run_router

    return run_router(config)


# Service commands: each module has `run(config, *, ident) -> int` (exit status). Imported only
# when used, so `hercs --help` stays fast.
SERVICE_EXAMPLES = {
    "replay": "hercs replay --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "clusterer": "hercs clusterer --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "learner": "hercs learner --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "evaluator": "hercs evaluator --connect tcp/127.0.0.1:7447 --run myrun --task push",
    "actor": "hercs actor --connect tcp/LEARNER_HOST:7447 --run myrun",
    "live": "hercs live --connect tcp/LEARNER_HOST:7447 --run myrun --rerun",
}

SERVICES: dict[str, tuple[str, str]] = {
    "replay": ("replay_service.service", "run the replay service (episode store, HER, samplers)"),
    "clusterer": ("clusterer.service", "run the clusterer (failed goals, k-means refits)"),
    "learner": ("learner.service", "run the DDPG learner (updates, weights, epochs)"),
    "actor": ("actors.service", "run a rollout actor (join a run with --connect and --run)"),
    "evaluator": ("actors.evaluator", "run the evaluator (deterministic test episodes)"),
    "live": ("apps.live_view", "stream a run to Rerun while it trains (what `hercs up "
                                "--rerun` starts; join a run with --connect and --run)"),
}


HARD_EXIT_SERVICES = frozenset(module for role, (module, _) in SERVICES.items()
                               if role != "live")
"""Services whose process ends with `exit_after_close` (not the live view: the Rerun SDK
flushes its recording in an exit handler)."""


def exit_after_close(code: int) -> NoReturn:
    """End a service process as soon as its orderly close is done, without interpreter
    teardown.

    When a service's `run` returns it has closed its Zenoh session, joined its threads (up
    to `hercs.service.THREAD_JOIN_S`) and made everything it acknowledged durable; teardown
    adds nothing but the finalisation of native threads, and there a clusterer stopped with
    SIGTERM once aborted (SIGABRT, glibc's "FATAL: exception not rethrown": a native thread
    unwound by the exiting interpreter; seen once in `make test` on a loaded machine, after
    a clean stop). So: wait for non-daemon threads as a normal exit would, flush the logs
    and the standard streams, and `os._exit`."""
    import logging
    import os
    import threading

    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _service_command(module: str) -> Command:
    def command(args: argparse.Namespace, config: HercsConfig) -> int:
        from importlib import import_module

        code = int(import_module(module).run(config, ident=args.ident))
        if module in HARD_EXIT_SERVICES:
            exit_after_close(code)
        return code

    return command


def _cmd_plot(args: argparse.Namespace) -> int:
    from apps.plots import run_plot
    from hercs.errors import HercsError
    from hercs.rundir import METRICS, require_run_dir

    try:
        for run_dir in args.run_dirs:  # what a folder lacks, before plots reads any
            require_run_dir(run_dir, needs=(METRICS,))
        return run_plot(args.run_dirs, args.output, reference=args.reference, table=args.table,
                        xmax=args.xmax, figure=args.figure, band=args.band)
    except HercsError as exc:
        print(f"hercs plot: {exc}", file=sys.stderr)
        return 2




def _cmd_view(args: argparse.Namespace) -> int:
    from apps.view import run_view

    return run_view(args.path, save=args.save, episodes=args.episodes, web=args.web,
                    web_port=args.web_port, grpc_port=args.grpc_port,
                    open_browser=not args.no_browser)


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, Command]]:
    parser = argparse.ArgumentParser(
        prog="hercs",
        description="Hindsight Experience Replay with Cluster-based Sampling, as distributed "
                    "services over Eclipse Zenoh.",
    )
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
                    "live view (apps/live_view.py), which training never waits for. Example: "
                    "hercs up --task push --method her-cs --epochs 50 --seed 1",
    )
    add_config_arguments(p, "up")
    add_rerun_arguments(p)
    p.add_argument("--tensorboard", action="store_true",
                   help="also write TensorBoard event files to RUN/tensorboard/ (the scalars "
                        "of metrics.csv; view with `tensorboard --logdir runs/`)")
    p.add_argument("--resume", metavar="RUN_DIR",
                   help="continue the run in RUN_DIR (e.g. runs/push-her-cs-s1-…) where it "
                        "stopped: the replay reloads its log, the learner its checkpoint, the "
                        "clusterer asks the replay; metrics.csv goes on from the last epoch")
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
    from apps.slurm import add_submit_arguments

    add_submit_arguments(p)
    commands["slurm"] = _cmd_slurm

    p = sub.add_parser("router", help="run a standalone Zenoh router (e.g. --listen "
                                      "tcp/0.0.0.0:7447) until Ctrl-C",
                       description="Route one or more runs' traffic; logs every hercs process "
                                   "that joins or leaves. Example: hercs router --tls-dir certs "
                                   "--listen tls/0.0.0.0:7447")
    add_config_arguments(p, "router")
    commands["router"] = _cmd_router

    for name, (module, help_text) in SERVICES.items():
        p = sub.add_parser(name, help=help_text,
                           description=f"{help_text[0].upper()}{help_text[1:]}: one process of "
                                       "a run, what `hercs up` and docker-compose.yml start. "
                                       f"Example: {SERVICE_EXAMPLES[name]}")
        add_config_arguments(p, name)
        if name == "live":
            add_rerun_arguments(p)
        p.add_argument("--id", dest="ident", help="process id (default: host name + short uuid)")
        commands[name] = _service_command(module)

    p = sub.add_parser("plot", help="learning curves (PNG) and milestone tables of run folders",
                       description="10-epoch mean of the seed mean of the success rate per "
                                   "epoch, with a bootstrap 95 % interval band (and/or the "
                                   "min–max band), one panel per task, the legend beside it; "
                                   "milestone tables on stdout. A folder named twice is read "
                                   "once.")
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="run folders (config.yaml + "
                   "metrics.csv)")
    p.add_argument("-o", "--output", required=True, metavar="FIG.png", help="figure to write")
    p.add_argument("--reference", action="store_true",
                   help="overlay the authors' curves (docs/reference/authors_success_rates.csv)")
    p.add_argument("--table", metavar="FILE.md", help="also write the tables here")
    p.add_argument("--xmax", type=int, metavar="EPOCH",
                   help="x axis end (default: the last epoch of our runs; 200 with --figure 2)")
    p.add_argument("--band", choices=BANDS, default=DEFAULT_BAND,
                   help="ci: bootstrap 95 %% interval of the seed mean (default); minmax: "
                        "min–max over seeds; both: the interval and, lighter, the min–max")
    p.add_argument("--figure", type=int, choices=[2],
                   help="the paper's figure layout: 2 = Fig. 2 (2x3 panels: HER vs HER-CS and "
                        "HER-EBP vs HER-EBP-CS on Push, PickAndPlace, Slide; authors dashed)")

    p = sub.add_parser("view", help="open (or --save) a Rerun recording of a run's episode log",
                       description="3D trajectories of gripper, object and goal per episode, "
                                   "success, clusters, failed goals, centroids and the learning "
                                   "curve (entity paths: see apps/view.py).")
    p.add_argument("path", metavar="PATH", help="episodes.mcap or a run directory")
    p.add_argument("--save", metavar="OUT.rrd", help="write an .rrd file instead of a viewer")
    p.add_argument("--episodes", metavar="SELECTION",
                   help="episode ids: '0:100', '5,7,9', '0:2000:10', 'last:20', "
                        "'spread:200' (every n-th, at most 200), 'all' (default: the last "
                        "epoch's episodes)")
    p.add_argument("--web", action="store_true",
                   help="serve the web viewer (http://localhost:9090) until Ctrl-C")
    p.add_argument("--web-port", type=int, metavar="PORT", help="web viewer's HTTP port "
                   "(9090)")
    p.add_argument("--grpc-port", type=int, metavar="PORT", help="with --web: the port the "
                   "recording is served on to the viewer (9876)")
    p.add_argument("--no-browser", action="store_true", help="with --web: do not open a browser")

    p = sub.add_parser("eval", help="evaluate a run's trained policy; record a video",
                       description="Loads a checkpoint (no service needed), runs deterministic "
                                   "episodes and reports success and final distance; --video "
                                   "records them (MuJoCo offscreen: EGL, else OSMesa). Example: "
                                   "hercs eval runs/RUN --video policy.mp4")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder (runs/RUN)")
    p.add_argument("--checkpoint", metavar="NAME", help="best (default when kept), latest, "
                   "epoch-N, or a file")
    p.add_argument("--episodes", type=int, default=20, help="episodes to run (default 20)")
    p.add_argument("--seed", type=int, help="draw goals from this seed (default: the goals "
                   "the run's evaluator used for that epoch)")
    p.add_argument("--video", metavar="OUT.mp4", help="record the episodes (25 fps)")
    p.add_argument("--rerun-save", metavar="OUT.rrd", help="record the camera images in Rerun")

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


def _cmd_eval(args: argparse.Namespace) -> int:
    from apps.policy_eval import run_eval

    return run_eval(args.run_dir, checkpoint=args.checkpoint, episodes=args.episodes,
                    seed=args.seed, video=args.video, rerun_save=args.rerun_save)


def _cmd_certs(args: argparse.Namespace) -> int:
    from apps.certs import run_certs

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
    "eval": _needs_extras(_cmd_eval)}


ENV_COMMANDS = frozenset({"up", "actor", "evaluator"})
"""Commands that make envs, themselves or in their children: before anything starts they check
that the task's env can be made here (the v1 envs need `make mujoco-py`). A remote actor, which
learns its task from the run, meets a missing mujoco-py when it makes its envs instead."""


def main(argv: list[str] | None = None) -> int:
    parser, commands = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    if args.command in NO_CONFIG_COMMANDS:
        return NO_CONFIG_COMMANDS[args.command](args)
    try:
        config = resolve_config(args)
    except ConfigError as exc:
        print(f"hercs {args.command}: invalid configuration: {exc}", file=sys.stderr)
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
    if args.command in ENV_COMMANDS:
        from hercs.envs import check_env

        try:
            check_env(config.task.spec)
        except ConfigError as exc:
            print(f"hercs {args.command}: {exc}", file=sys.stderr)
            return 2
    return commands[args.command](args, config)


if __name__ == "__main__":
    sys.exit(main())
