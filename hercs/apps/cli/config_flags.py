"""How every `hercs` command builds its one `HercsConfig` (hercs/apps/cli/main.py): defaults
(docs/DESIGN.md §4) ← `--config FILE.yaml` ← shortcut flags (`--task`, `--method`, …) ←
`--set section.field=value`; which command takes which flag; `--resume`; the Rerun flags."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from hercs.apps.tracking.flags import backends_override
from hercs.config import HercsConfig, apply_overrides, load_yaml, workers_overrides
from hercs.errors import ConfigError
from hercs.rl.code_names import ANY, trust_task
from hercs.rl.methods import METHODS
from hercs.rl.task_registry import TASKS
from hercs.run.rundir import RunDir

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
    # actors and the live view take everything else from the run's replay
    "actor": ("run", "run_dir", "connect", "security"),
    "live": ("run", "run_dir", "connect", "security"),
}
JOINERS = frozenset({"actor", "live"})
"""Commands that join a running run and, without --connect, read its router.json."""


def add_config_arguments(parser: argparse.ArgumentParser, command: str) -> None:
    """--config and --set, plus the shortcuts `command` uses (`FLAGS_OF`)."""
    flags = FLAGS_OF[command]
    group = parser.add_argument_group("configuration")
    group.add_argument("--config", metavar="FILE", help="YAML config (partial is fine)")
    group.add_argument("--set", dest="overrides", action="append", default=[],
                       metavar="SECTION.FIELD=VALUE",
                       help="override any config field, e.g. --set ddpg.lr_actor=5e-4")
    add_trust_argument(group)
    helps = {
        "task": dict(metavar="TASK",
                     help=f"task: a Fetch preset {sorted(TASKS)} (Fetch*-v4; --set "
                          "task.env_version=v1: the authors' Fetch*-v1), a gymnasium id of a "
                          "goal environment (PointMaze_UMaze-v3, HandReach-v3, …) or "
                          "package.module:factory"),
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


def add_trust_argument(group: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    group.add_argument("--trust-task", action="store_true",
                       help="import the environment code (package.module:factory) that a run "
                            "folder's config or checkpoint names; without it hercs imports "
                            "only code you name yourself (docs/SECURITY.md)")


def trust_named_tasks(args: argparse.Namespace) -> None:
    """Trust the task names the user gave on this command line (`--task`, `--set
    task.name=`, a `--config` file's) and, with --trust-task, any: `hercs.rl.code_names`."""
    if getattr(args, "trust_task", False):
        trust_task(ANY)
    named = [getattr(args, "task", None), _file_task(getattr(args, "config", None))]
    named += [item.partition("=")[2].strip() for item in getattr(args, "overrides", [])
              if item.partition("=")[0].strip() == "task.name"]
    for name in named:
        if name:
            trust_task(name)


def _file_task(path: str | None) -> str | None:
    """task.name of the YAML file `path` as written (load_yaml reports a bad file)."""
    if not path:
        return None
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return None
    task = data.get("task") if isinstance(data, dict) else None
    name = task.get("name") if isinstance(task, dict) else None
    return name if isinstance(name, str) else None


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
    saved = RunDir(run_dir).config
    if not saved.is_file():
        raise ConfigError(f"--resume {args.resume}: no config.yaml there; give the folder of a "
                          "run that `hercs up` started (runs/RUN)")
    config = load_yaml(saved)
    return apply_overrides(config, [f"run.name={run_dir.resolve().name}",
                                    f"run.run_dir={run_dir.resolve().parent}"])


def resolve_config(args: argparse.Namespace) -> HercsConfig:
    trust_named_tasks(args)  # before any config is built: building one resolves its task
    if getattr(args, "restart", False) and not getattr(args, "resume", None):
        raise ConfigError("--restart starts a run over in its folder: give it with --resume "
                          "RUN_DIR (hercs up --resume runs/RUN --restart)")
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
    tracks = track_overrides(config, args)
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
    return apply_overrides(config, overrides + tracks + rerun_overrides(args)
                           + list(args.overrides))


def track_overrides(config: HercsConfig, args: argparse.Namespace) -> list[str]:
    """`tracking.backends` with the trackers `--track` names (and `--tensorboard`, its older
    spelling) added to those the config already has; none when neither is given."""
    named = [*(getattr(args, "track", None) or []),
             *(["tensorboard"] if getattr(args, "tensorboard", False) else [])]
    return backends_override(config.tracking.backends, named)


def join_endpoints(args: argparse.Namespace, config: HercsConfig) -> HercsConfig | None:
    """An actor's or live view's config with `transport.connect` = the endpoints the run's
    `hercs up` recorded in RUN_DIR/RUN/router.json, when --connect is not given.

    With --run-dir given it waits for the file (`transport.wait_s`, 0 = for ever: a Slurm
    job's actors start with the run, before its router listens); None when it gave up.
    Without --run-dir it uses runs/RUN/router.json if there is one, else the config's
    `connect` as before."""
    from hercs.run.router_record import read_router, wait_router
    from hercs.run.rundir import run_dir_of

    if getattr(args, "connect", None) or not config.run.name:
        if getattr(args, "run_dir", None) is not None and not config.run.name:
            raise ConfigError("--run-dir: give --run RUN too (the router is recorded in "
                              "RUN_DIR/RUN/router.json)")
        return config
    run_dir = run_dir_of(config.run)
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
        default = config.transport.connect == HercsConfig().transport.connect
        print(f"hercs {args.command}: no {RunDir(run_dir).router} (no run {config.run.name} is "
              f"running in {run_dir.parent}): connecting to {', '.join(config.transport.connect)}"
              f" ({'the default ' if default else ''}transport.connect) and waiting for a router "
              "there; give --connect ENDPOINT (the run's router, e.g. tls/HOST:7447), or "
              "--run-dir DIR if the run's folder is elsewhere", file=sys.stderr, flush=True)
        return config
    listed = yaml.safe_dump(record.endpoints_for(), default_flow_style=True).strip()
    return apply_overrides(config, [f"transport.connect={listed}"])
