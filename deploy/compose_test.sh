#!/usr/bin/env bash
# `make compose-test`: run docker-compose.yml for real, on a machine that reaches no image
# registry (only Debian's and PyPI's package mirrors), then leave nothing behind.
#
#   engine     use a running Docker engine (DOCKER_HOST or /var/run/docker.sock) if there is one;
#              else install Debian's docker.io + docker-compose + debootstrap and start dockerd
#              in its own network and mount namespaces (`unshare --net --mount`): its bridge,
#              iptables rules and published ports exist only there, its mounts vanish with it.
#              Containers reach each other by service name on compose's default bridge network,
#              which works unchanged inside that namespace (no override file).
#   base       `debootstrap --variant=minbase bookworm` + python3.11 + python3-venv, trimmed,
#              `docker import`ed as hercs-ci-base:<key> (no pull)
#   wheelhouse `pip wheel` of torch==2.13.0 (this machine's pip resolves it to the local CPU
#              wheel) and pyproject.toml's dependencies, linked into deploy/wheelhouse/
#   build      `docker build --target services` with BASE_IMAGE=hercs-ci-base:<key>,
#              PIP_NO_INDEX=1 and PIP_FIND_LINKS=/wheels, tagged hercs:latest
#   run        `hercs certs`, then `compose up --scale actor=4 --exit-code-from learner`
#              (FetchReach, HERCS_EPOCHS=2, tiny HERCS_SET); checks that every role joined the
#              router, the learner exited 0, the stack stopped by itself, the `runs` volume
#              holds config.yaml, episodes.mcap, metrics.csv and checkpoints/learner.pt, and a
#              second `up` with the same HERCS_RUN is refused; then `down -v`.
#
# Where no engine can be had (not root, no apt-get, dockerd will not start) it prints
# "SKIPPED: <reason>" and exits 0; any later failure exits 1. HERCS_COMPOSE_TEST=skip skips.
#
# Caches, keyed by content, outside the clone (HERCS_CI_CACHE, default /var/cache/hercs-ci):
# base/<key>.tar.gz, wheelhouse/<key>/, docker/ (the engine's data root: imported base image
# and build cache), last-run/ (this run's logs, certificates and results). A second run skips
# debootstrap, pip and most of the build. `deploy/compose_test.sh clean` deletes the cache.
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
CACHE=${HERCS_CI_CACHE:-/var/cache/hercs-ci}
STATE=${HERCS_CI_STATE:-/run/hercs-ci-docker}   # the private engine: socket, pidfile, exec root
WORK=$CACHE/last-run
PY=${HERCS_CI_PYTHON:-$REPO/.venv/bin/python}
HERCS=${HERCS_CI_HERCS:-$REPO/.venv/bin/hercs}
PROJECT=hercs-ci
ACTORS=${HERCS_CI_ACTORS:-4}
UP_TIMEOUT_S=${HERCS_CI_UP_TIMEOUT_S:-900}
SUITE=bookworm
MIRROR=${HERCS_CI_DEBIAN_MIRROR:-http://deb.debian.org/debian}
INCLUDE=python3.11,python3-venv
IMAGE=hercs:latest

# The run: short FetchReach, a few cycles per epoch (docker-compose.yml reads these).
export HERCS_TASK=${HERCS_TASK:-reach}
export HERCS_METHOD=${HERCS_METHOD:-her-cs}
export HERCS_EPOCHS=${HERCS_EPOCHS:-2}
export HERCS_SET=${HERCS_SET:-training.cycles_per_epoch=10 training.eval_episodes=5}
export HERCS_RUN=${HERCS_RUN:-ci-$(date +%Y%m%d-%H%M%S)}
export HERCS_RESUME=0
export COMPOSE_PROJECT_NAME=$PROJECT
export DOCKER_BUILDKIT=0           # Debian's engine has no buildx: the classic builder
export COMPOSE_DOCKER_CLI_BUILD=0

OWN_ENGINE=0         # 1 once we started dockerd (then we stop it)
DOCKERD_PID=
LAUNCHER_PID=        # the `unshare` that runs it
DOCKERD_MNTNS=
COMPOSE=()
LINKED_WHEELS=()
TIMES=()
T0=$(date +%s%N)

log() { printf '[compose-test %s] %s\n' "$(date +%H:%M:%S)" "$*"; }
SKIPPED=
skip() { SKIPPED=$*; printf 'SKIPPED: %s\n' "$*"; exit 0; }
die() { printf 'FAILED: %s\n' "$*" >&2; exit 1; }
tail_of() {
    if [ -f "$1" ]; then { echo "--- last lines of $1:"; tail -n "${2:-40}" "$1"; } >&2; fi
}

PHASE=
PHASE_T=
phase() {  # phase NAME: closes the previous phase (prints its time) and opens NAME
    local now; now=$(date +%s%N)
    if [ -n "$PHASE" ]; then
        local secs; secs=$(awk -v a="$PHASE_T" -v b="$now" 'BEGIN{printf "%.1f", (b-a)/1e9}')
        TIMES+=("$(printf '%-11s %7ss' "$PHASE" "$secs")")
        log "phase $PHASE done in ${secs}s"
    fi
    PHASE=$1
    PHASE_T=$now
    [ -n "$PHASE" ] && log "phase $PHASE"
    return 0
}

print_times() {
    [ ${#TIMES[@]} -gt 0 ] || return 0
    local total; total=$(awk -v a="$T0" -v b="$(date +%s%N)" 'BEGIN{printf "%.1f", (b-a)/1e9}')
    echo "compose-test timings:"
    printf '  %s\n' "${TIMES[@]}"
    printf '  %-11s %7ss\n' total "$total"
}

# -- the private engine -------------------------------------------------------------------------
docker_ok() { timeout 20 docker version >/dev/null 2>&1; }

ns_pids() {  # the processes living in the private engine's mount namespace (ours)
    [ -n "$DOCKERD_MNTNS" ] || return 0
    # never the namespace this script lives in (that would be every process of the machine)
    [ "$DOCKERD_MNTNS" != "$(readlink /proc/$$/ns/mnt)" ] || return 0
    local p
    for p in /proc/[0-9]*; do
        [ "$(readlink "$p/ns/mnt" 2>/dev/null)" = "$DOCKERD_MNTNS" ] && echo "${p#/proc/}"
    done
    return 0
}

stop_engine() {  # stop the dockerd we started (by its pid), then whatever stayed in its namespace
    [ -n "$DOCKERD_PID" ] || return 0
    if kill -0 "$DOCKERD_PID" 2>/dev/null; then
        # containers first (an interrupted run leaves them running), then the engine
        DOCKER_HOST="unix://$STATE/docker.sock" timeout 60 sh -c \
            'docker ps -q | xargs -r docker rm -f' >/dev/null 2>&1 || true
        kill -TERM "$DOCKERD_PID" 2>/dev/null || true
        for _ in $(seq 1 60); do kill -0 "$DOCKERD_PID" 2>/dev/null || break; sleep 0.5; done
    fi
    if [ -n "$LAUNCHER_PID" ]; then  # unshare exits once dockerd has
        for _ in $(seq 1 10); do kill -0 "$LAUNCHER_PID" 2>/dev/null || break; sleep 0.5; done
        wait "$LAUNCHER_PID" 2>/dev/null || true
        LAUNCHER_PID=
    fi
    local left; left=$(ns_pids)
    if [ -n "$left" ]; then
        log "killing what is left in the engine's namespace: $(echo "$left" | tr '\n' ' ')"
        # shellcheck disable=SC2086
        kill -KILL $left 2>/dev/null || true
        sleep 1
    fi
    # The engine's mounts lived in its private mount namespace; sweep any that leaked anyway.
    findmnt -rn -o TARGET | grep -E "^($STATE|$CACHE/docker)(/|$)" | sort -r \
        | while read -r m; do umount -l "$m" 2>/dev/null || true; done || true
    rm -rf "$STATE"
    DOCKERD_PID=
    DOCKERD_MNTNS=
}

stop_stale_engine() {  # a private engine left by an interrupted run: by its recorded pid
    local pid
    pid=$(cat "$STATE/dockerd.pid" 2>/dev/null || true)
    if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null \
        && tr '\0' ' ' <"/proc/$pid/cmdline" | grep -q -- "$STATE/docker.sock"; then
        log "stopping the engine an interrupted run left (pid $pid)"
        DOCKERD_PID=$pid
        DOCKERD_MNTNS=$(readlink "/proc/$pid/ns/mnt" || true)
        stop_engine
    fi
    rm -rf "$STATE"
}

start_engine() {
    local attempt
    for attempt in 1 2; do
        mkdir -p "$STATE" "$CACHE/docker"
        log "starting dockerd in its own network + mount namespace (socket $STATE/docker.sock)"
        # lo up inside the new network namespace; no other interface: no route out of it.
        # shellcheck disable=SC2016  # $1/$2 are expanded by the inner sh
        setsid unshare --net --mount --propagation private --fork -- sh -c '
            ip link set lo up && exec dockerd \
              --data-root "$1/docker" --exec-root "$2/exec" --pidfile "$2/dockerd.pid" \
              -H "unix://$2/docker.sock" --containerd-namespace hercs-ci \
              --containerd-plugins-namespace hercs-ci-plugins --log-level warn' \
            sh "$CACHE" "$STATE" >"$WORK/dockerd.log" 2>&1 </dev/null &
        local launcher=$!
        LAUNCHER_PID=$launcher
        export DOCKER_HOST="unix://$STATE/docker.sock"
        for _ in $(seq 1 120); do
            if [ -z "$DOCKERD_PID" ] && [ -s "$STATE/dockerd.pid" ]; then
                DOCKERD_PID=$(cat "$STATE/dockerd.pid")
                DOCKERD_MNTNS=$(readlink "/proc/$DOCKERD_PID/ns/mnt" || true)
                OWN_ENGINE=1
            fi
            docker_ok && return 0
            kill -0 "$launcher" 2>/dev/null || break
            sleep 0.5
        done
        tail_of "$WORK/dockerd.log" 20
        stop_engine
        kill "$launcher" 2>/dev/null || true
        if [ "$attempt" = 1 ] && [ -d "$CACHE/docker" ]; then
            log "dockerd did not come up; retrying once with an empty data root"
            rm -rf "$CACHE/docker"
        fi
    done
    return 1
}

ensure_packages() {
    local missing=()
    command -v dockerd >/dev/null || missing+=(docker.io)
    command -v debootstrap >/dev/null || missing+=(debootstrap)
    if ! docker compose version >/dev/null 2>&1 && ! command -v docker-compose >/dev/null; then
        missing+=(docker-compose)
    fi
    [ ${#missing[@]} -eq 0 ] && return 0
    command -v apt-get >/dev/null || skip "no apt-get to install ${missing[*]}"
    log "apt-get install ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    if ! apt-get install -y --no-install-recommends "${missing[@]}" >"$WORK/apt.log" 2>&1; then
        apt-get update >>"$WORK/apt.log" 2>&1 || true
        apt-get install -y --no-install-recommends "${missing[@]}" >>"$WORK/apt.log" 2>&1 \
            || { tail_of "$WORK/apt.log" 15; skip "apt-get install ${missing[*]} failed"; }
    fi
}

pick_compose() {
    if docker compose version >/dev/null 2>&1; then
        COMPOSE=(docker compose)
    elif command -v docker-compose >/dev/null; then
        COMPOSE=(docker-compose)
    else
        skip "no docker compose (plugin) and no docker-compose"
    fi
    COMPOSE+=(--project-name "$PROJECT" --file "$REPO/docker-compose.yml")
    log "compose: ${COMPOSE[*]:0:2} ($("${COMPOSE[@]}" version --short 2>/dev/null || true))"
}

compose() { "${COMPOSE[@]}" "$@"; }

# -- cleanup (always) ---------------------------------------------------------------------------
cleanup() {
    local status=$?
    set +e
    phase teardown
    if [ ${#COMPOSE[@]} -gt 0 ] && docker_ok; then
        compose down -v --remove-orphans --timeout 10 >>"$WORK/down.log" 2>&1
        local left
        left=$(docker ps -aq --filter "label=com.docker.compose.project=$PROJECT")
        if [ -n "$left" ]; then
            echo "FAILED: containers left after down: $left" >&2
            status=1
        fi
        # our engine only: replaced images go, the tagged ones (and their build cache) stay
        [ "$OWN_ENGINE" = 1 ] && docker image prune -f >/dev/null 2>&1
    fi
    local wheel
    for wheel in "${LINKED_WHEELS[@]}"; do rm -f "$REPO/deploy/wheelhouse/$wheel"; done
    [ "$OWN_ENGINE" = 1 ] && { log "stopping dockerd (pid $DOCKERD_PID)"; stop_engine; }
    phase ""
    print_times
    if [ -n "$SKIPPED" ] && [ "$status" = 0 ]; then
        echo "compose-test: SKIPPED: $SKIPPED"
    elif [ "$status" = 0 ]; then
        echo "compose-test: OK"
    else
        echo "compose-test: FAILED (logs: $WORK)" >&2
    fi
    exit "$status"
}

# -- the phases ---------------------------------------------------------------------------------
base_image() {  # sets BASE to a local image tag, built by debootstrap (cached by content)
    if [ -n "${HERCS_CI_BASE_IMAGE:-}" ]; then BASE=$HERCS_CI_BASE_IMAGE; return; fi
    local recipe key tarball rootfs
    recipe="debootstrap --variant=minbase --include=$INCLUDE $SUITE $MIRROR; trim v1"
    key=$(printf '%s' "$recipe" | sha256sum | cut -c1-12)
    BASE=hercs-ci-base:$key
    if docker image inspect "$BASE" >/dev/null 2>&1; then
        log "base image $BASE is already in the engine"
        return
    fi
    tarball=$CACHE/base/$SUITE-$key.tar.gz
    if [ ! -s "$tarball" ]; then
        command -v debootstrap >/dev/null || die "debootstrap is missing"
        rootfs=$CACHE/base/rootfs.$$
        mkdir -p "$CACHE/base"
        log "debootstrap $SUITE ($INCLUDE) -> $tarball"
        if ! debootstrap --variant=minbase --include="$INCLUDE" "$SUITE" "$rootfs" "$MIRROR" \
                >"$WORK/debootstrap.log" 2>&1; then
            tail_of "$WORK/debootstrap.log" 20
            findmnt -rn -o TARGET | grep "^$rootfs/" | sort -r | xargs -r umount -l || true
            rm -rf "$rootfs"
            die "debootstrap failed"
        fi
        # Trim what no container uses: apt's caches and lists, docs, man pages, locales.
        rm -rf "$rootfs"/var/cache/apt/* "$rootfs"/var/lib/apt/lists/* "$rootfs"/usr/share/doc/* \
               "$rootfs"/usr/share/man/* "$rootfs"/usr/share/info/* "$rootfs"/usr/share/locale/*
        tar -C "$rootfs" --numeric-owner -czf "$tarball.tmp" .
        mv "$tarball.tmp" "$tarball"
        rm -rf "$rootfs"
    fi
    log "docker import $tarball $BASE"
    docker import "$tarball" "$BASE" >/dev/null
}

wheelhouse() {  # pyproject.toml's dependencies as wheels, cached by the requirement list
    local reqs key dir
    reqs=$("$PY" - "$REPO/pyproject.toml" <<'EOF'
import sys, tomllib
meta = tomllib.load(open(sys.argv[1], "rb"))
print("torch==2.13.0")  # the CPU build: the Dockerfile's pin
print("\n".join(meta["project"]["dependencies"] + meta["build-system"]["requires"]))
EOF
)
    key=$(printf '%s\n%s\n' "$reqs" "$("$PY" -c 'import sys; print(sys.version_info[:2])')" \
          | sha256sum | cut -c1-12)
    dir=$CACHE/wheelhouse/$key
    if [ ! -f "$dir/.complete" ]; then
        log "pip wheel -> $dir"
        rm -rf "$dir.tmp"
        mkdir -p "$dir.tmp"
        printf '%s\n' "$reqs" >"$dir.tmp/requirements.txt"
        "$PY" -m pip wheel --quiet --wheel-dir "$dir.tmp" -r "$dir.tmp/requirements.txt" \
            >"$WORK/pip-wheel.log" 2>&1 || { tail_of "$WORK/pip-wheel.log" 20; die "pip wheel failed"; }
        ls "$dir.tmp"/torch-2.13.0+cpu-*.whl >/dev/null 2>&1 \
            || die "the wheelhouse has no CPU build of torch 2.13.0: $(cd "$dir.tmp" && echo torch-*)"
        touch "$dir.tmp/.complete"
        rm -rf "$dir"
        mv "$dir.tmp" "$dir"
    else
        log "wheelhouse $dir is cached"
    fi
    local wheel
    for wheel in "$dir"/*.whl; do
        wheel=$(basename "$wheel")
        if [ "$REPO/deploy/wheelhouse/$wheel" -ef "$dir/$wheel" ]; then
            LINKED_WHEELS+=("$wheel")   # linked by an interrupted run: ours to remove too
            continue
        fi
        [ -e "$REPO/deploy/wheelhouse/$wheel" ] && continue   # someone else's: left alone
        ln "$dir/$wheel" "$REPO/deploy/wheelhouse/$wheel" 2>/dev/null \
            || cp "$dir/$wheel" "$REPO/deploy/wheelhouse/$wheel"
        LINKED_WHEELS+=("$wheel")
    done
    log "wheelhouse: $(find "$dir" -name '*.whl' | wc -l) wheels, $(du -sh "$dir" | cut -f1)"
}

docker_build() {  # docker_build TARGET TAG: the offline build (base image + wheelhouse)
    docker build --target "$1" -t "$2" --build-arg "BASE_IMAGE=$BASE" \
        --build-arg PIP_NO_INDEX=1 --build-arg PIP_FIND_LINKS=/wheels "$REPO" \
        >>"$WORK/build.log" 2>&1 || { tail_of "$WORK/build.log" 40; die "docker build --target $1 failed"; }
}

build_image() {
    log "docker build (BASE_IMAGE=$BASE, PIP_NO_INDEX=1, PIP_FIND_LINKS=/wheels)"
    # The deps stage is tagged so that the clean-up's `image prune` keeps it as build cache;
    # it changes only with pyproject.toml (then the old one is pruned).
    docker_build deps hercs-ci-cache:deps
    docker_build services "$IMAGE"
    log "image $IMAGE (target services): $(image_mb "$IMAGE") MB; base $BASE: $(image_mb "$BASE") MB"
    if [ "${HERCS_CI_FULL:-0}" = 1 ]; then  # the default target too, for comparison
        docker_build full hercs:full
        log "image hercs:full (target full): $(image_mb hercs:full) MB"
    fi
    # The services image starts the CLI and its service modules, without the view/plot deps.
    docker run --rm --network none --entrypoint python3 "$IMAGE" -c '
import importlib, sys
for m in ("hercs.apps.cli", "hercs.apps.launch.router", "hercs.replay_service.replay_shell", "hercs.clusterer.clusterer_shell",
          "hercs.learner.learner_shell", "hercs.actors.actor_shell", "hercs.actors.evaluator"):
    importlib.import_module(m)
heavy = sorted({"rerun", "matplotlib", "pyarrow", "imageio_ffmpeg"} & set(sys.modules))
assert not heavy, heavy
' >"$WORK/import-check.log" 2>&1 || { tail_of "$WORK/import-check.log"; die "services image cannot import the services"; }
    docker run --rm --network none "$IMAGE" --help >/dev/null || die "hercs --help fails in $IMAGE"
}

image_mb() { docker image inspect -f '{{.Size}}' "$1" | awk '{printf "%d", $1/1e6}'; }

compose_run() {
    rm -rf "$WORK/certs"
    "$HERCS" certs "$WORK/certs" --host router >"$WORK/certs.log" 2>&1 \
        || { tail_of "$WORK/certs.log"; die "hercs certs failed"; }
    export HERCS_CERTS=$WORK/certs
    compose down -v --remove-orphans --timeout 5 >"$WORK/down-before.log" 2>&1 || true
    log "compose up --scale actor=$ACTORS --exit-code-from learner (run $HERCS_RUN:" \
        "$HERCS_TASK, $HERCS_EPOCHS epochs, HERCS_SET=$HERCS_SET)"
    local status=0
    timeout "$UP_TIMEOUT_S" "${COMPOSE[@]}" up --no-build --no-color --scale "actor=$ACTORS" \
        --exit-code-from learner >"$WORK/compose-up.log" 2>&1 || status=$?
    compose ps -a >"$WORK/compose-ps.log" 2>&1 || true
    compose logs --no-color router >"$WORK/router.log" 2>&1 || true
    if [ "$status" != 0 ]; then
        tail_of "$WORK/compose-up.log" 60
        [ "$status" = 124 ] && die "compose up did not finish within ${UP_TIMEOUT_S}s"
        die "compose up exited $status (the learner's exit code)"
    fi
    log "learner exited 0; compose up returned by itself"

    # Every role joined the router, with 4 different actors.
    local role missing=()
    for role in replay clusterer learner evaluator; do
        grep -qE " $role [^ ]+ \(run $HERCS_RUN\) joined" "$WORK/router.log" || missing+=("$role")
    done
    local actors
    actors=$({ grep -oE " actor [^ ]+ \(run $HERCS_RUN\) joined" "$WORK/router.log" || true; } \
             | sort -u | wc -l)
    [ "$actors" -ge "$ACTORS" ] || missing+=("actor (only $actors of $ACTORS)")
    [ ${#missing[@]} -eq 0 ] || { tail_of "$WORK/router.log" 40; die "never joined: ${missing[*]}"; }
    log "router log: $(grep -c ' joined' "$WORK/router.log") joins, $(grep -c ' left' "$WORK/router.log") leaves"
    grep -E ' (joined|left)$' "$WORK/router.log" | sed 's/^/    /' | head -40 || true

    # The stack stopped by itself: no container of the project is still running, and every one
    # exited 0 (compose stops the rest once the learner exits; they stop cleanly on SIGTERM).
    local running failed
    running=$(docker ps -q --filter "label=com.docker.compose.project=$PROJECT")
    [ -z "$running" ] || die "containers still running after up returned: $running"
    # shellcheck disable=SC2046
    docker inspect -f '{{.Name}} {{.State.ExitCode}}' \
        $(docker ps -aq --filter "label=com.docker.compose.project=$PROJECT") >"$WORK/exit-codes.log"
    failed=$(awk '$2 != 0' "$WORK/exit-codes.log")
    [ -z "$failed" ] || { tail_of "$WORK/compose-up.log" 60; die "containers exited non-zero: $failed"; }
    log "all $(wc -l <"$WORK/exit-codes.log") containers exited 0"

    # The runs volume holds the run's files.
    local volume=${PROJECT}_runs
    docker run --rm --network none -v "$volume:/runs:ro" --entrypoint sh "$IMAGE" -c '
        set -e; cd "/runs/$1"
        for f in config.yaml episodes.mcap metrics.csv checkpoints/learner.pt; do
            test -s "$f" || { echo "missing or empty: $f"; exit 1; }
        done
        ls -la . checkpoints; echo "--- metrics.csv"; cut -d, -f1-6 metrics.csv' \
        sh "$HERCS_RUN" >"$WORK/volume.log" 2>&1 \
        || { tail_of "$WORK/volume.log"; die "the runs volume lacks a file of run $HERCS_RUN"; }
    local rows
    rows=$(awk '/^--- metrics.csv/{on=1; next} on' "$WORK/volume.log" | tail -n +2 | wc -l)
    [ "$rows" = "$HERCS_EPOCHS" ] || { cat "$WORK/volume.log"; die "metrics.csv has $rows rows, not $HERCS_EPOCHS"; }
    log "volume $volume: run $HERCS_RUN has config.yaml, episodes.mcap, checkpoints/learner.pt," \
        "metrics.csv with $rows epoch rows"
    sed 's/^/    /' "$WORK/volume.log"

    # A second `up` with the same run name is refused, not appended to the finished run.
    log "compose up again with HERCS_RUN=$HERCS_RUN: must be refused"
    status=0
    timeout 300 "${COMPOSE[@]}" up --no-build --no-color --scale actor=1 --exit-code-from learner \
        >"$WORK/compose-up-again.log" 2>&1 || status=$?
    [ "$status" != 0 ] || { tail_of "$WORK/compose-up-again.log"; die "a second up with the same run exited 0"; }
    grep -q "run '$HERCS_RUN' already exists" "$WORK/compose-up-again.log" \
        || { tail_of "$WORK/compose-up-again.log"; die "a second up failed without saying why"; }
    log "second up refused (exit $status): $(grep -m1 "already exists" "$WORK/compose-up-again.log" | sed 's/^[^|]*| //')"
}

clean_cache() {
    stop_stale_engine
    findmnt -rn -o TARGET | grep -E "^$CACHE/" | sort -r | xargs -r umount -l || true
    rm -rf "$CACHE"
    find "$REPO/deploy/wheelhouse" -name '*.whl' -delete 2>/dev/null || true
    echo "removed $CACHE"
}

main() {
    if [ "${1:-}" = clean ]; then clean_cache; return; fi
    case ${HERCS_COMPOSE_TEST:-} in skip|0|no) skip "HERCS_COMPOSE_TEST=$HERCS_COMPOSE_TEST";; esac
    [ -x "$HERCS" ] || skip "no $HERCS (run \`make install\` first)"
    if [ "$(id -u)" != 0 ]; then
        # debootstrap and a private engine both need root.
        skip "not root: cannot install Docker, start a private engine or debootstrap a base image"
    fi
    mkdir -p "$CACHE"
    # One run at a time: they share the engine's socket, data root and deploy/wheelhouse. The
    # owner's pid is in $CACHE/run.pid (a pid file, not flock: dockerd would inherit the lock).
    local owner waited=0
    while owner=$(cat "$CACHE/run.pid" 2>/dev/null) && [ -n "$owner" ] && [ "$owner" != $$ ] \
        && kill -0 "$owner" 2>/dev/null && grep -q compose_test "/proc/$owner/cmdline" 2>/dev/null; do
        [ "$waited" = 0 ] && log "another compose-test (pid $owner) is running; waiting for it"
        waited=$((waited + 5))
        [ "$waited" -le 1800 ] || die "another compose-test (pid $owner) still runs after 30 min"
        sleep 5
    done
    echo $$ >"$CACHE/run.pid"
    rm -rf "$WORK"
    mkdir -p "$WORK"
    log "logs, certificates and results: $WORK"

    phase engine
    trap cleanup EXIT
    trap 'exit 130' INT
    trap 'exit 143' TERM
    if [ -n "${DOCKER_HOST:-}" ] && docker_ok; then
        log "using the engine at DOCKER_HOST=$DOCKER_HOST"
    elif [ -z "${DOCKER_HOST:-}" ] && docker_ok; then
        log "using the running engine at /var/run/docker.sock"
    else
        unset DOCKER_HOST
        command -v unshare >/dev/null || skip "no unshare (util-linux)"
        command -v ip >/dev/null || skip "no ip (iproute2)"
        ensure_packages
        stop_stale_engine
        start_engine || skip "dockerd would not start (log: $WORK/dockerd.log)"
    fi
    ensure_packages
    pick_compose
    log "engine: $(docker version -f 'server {{.Server.Version}}, client {{.Client.Version}}')"

    phase base
    base_image
    phase wheelhouse
    wheelhouse
    phase build
    build_image
    phase run
    compose_run
}

main "$@"
