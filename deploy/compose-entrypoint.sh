#!/bin/sh
# The entrypoint of docker-compose.yml's services (in the image as /usr/local/bin/hercs-compose):
# `hercs "$@"`, plus two things compose's variables cannot express on their own.
#
# 1. HERCS_SET: whitespace-separated SECTION.FIELD=VALUE overrides, each passed on as its own
#    `--set` (e.g. HERCS_SET="training.cycles_per_epoch=5 training.eval_episodes=5").
# 2. A run name is a new run. `hercs replay` and `hercs learner` refuse (exit 2) a run folder
#    (--run-dir/--run) that already holds a trained epoch (metrics.csv) or a learner checkpoint,
#    so a second `docker compose up` never appends to a finished run's replay log and metrics.
#    HERCS_RESUME=1 continues such a run instead (after Ctrl-C or a crash), as
#    `hercs up --resume` does.
set -eu

command=${1:-}
run_dir=
run=
previous=
for arg in "$@"; do
    case $previous in
        --run-dir) run_dir=$arg ;;
        --run) run=$arg ;;
    esac
    previous=$arg
done

case $command in
    replay|learner)
        folder=${run_dir:-runs}/$run
        if [ -n "$run" ] && [ "${HERCS_RESUME:-0}" != 1 ] \
            && { [ -s "$folder/metrics.csv" ] || [ -e "$folder/checkpoints/learner.pt" ]; }; then
            echo "hercs $command: run '$run' already exists in $folder (metrics.csv or" \
                 "checkpoints/learner.pt): a second \`docker compose up\` would append to it." >&2
            echo "  Start a new run:  HERCS_RUN=<new name> docker compose up …" >&2
            echo "  Continue it:      HERCS_RESUME=1 HERCS_RUN=$run docker compose up …" >&2
            echo "  Delete all runs:  docker compose down -v" >&2
            exit 2
        fi
        ;;
esac

set -f  # HERCS_SET is split on whitespace, never globbed
for override in ${HERCS_SET:-}; do
    set -- "$@" --set "$override"
done
exec hercs "$@"
