#!/usr/bin/env bash
# `make mujoco-py`: the authors' environment, Fetch*-v1 on mujoco-py and MuJoCo 2.1, for
# `--set task.env_version=v1`, from the package registries only (Debian's and PyPI):
#
#   system   what mujoco-py's extension compiles and links against: a C compiler, Python's
#            headers, OSMesa and GL (libosmesa6-dev, libgl1-mesa-dev) and patchelf. As root,
#            apt-get installs the missing ones; otherwise the script names them and stops.
#   mujoco   MuJoCo 2.1.0's Linux binaries, out of PyPI's free-mujoco-py 2.1.6 wheel
#            (mujoco_py/binaries/linux/mujoco210), into <venv>/mujoco210 (hercs.rl.envs.MUJOCO210)
#   extra    pip install -e '.[v1]': mujoco-py-cython3 and what it needs, pinned in pyproject.toml
#   compile  the first `import mujoco_py` cythonizes and compiles its extension (about 15 s on
#            2 cores); then patchelf gives the extension <venv>/mujoco210/bin as its RUNPATH,
#            so that every process finds libmujoco210.so without LD_LIBRARY_PATH set at its
#            start (mujoco-py removes the RUNPATH its build sets; hercs.rl.envs refuses an
#            extension compiled again since, instead of letting mujoco-py compile it once more
#            in every process: run `make mujoco-py` again)
#   check    FetchPush-v1 made through hercs.rl.envs, reset and stepped, in a fresh process
#            with neither MUJOCO_PY_MUJOCO_PATH nor LD_LIBRARY_PATH set
#
# About a minute on a fresh Debian bookworm machine with 2 cores (apt included), half that where
# the Debian packages are there; a second run finds everything in place and only checks
# (seconds). VENV (default .venv) names the virtualenv, which must already hold hercs
# (`make install`).
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=${VENV:-$REPO/.venv}
PY=$VENV/bin/python
MUJOCO=$VENV/mujoco210
BINARIES=free-mujoco-py==2.1.6
BINARIES_DIR=mujoco_py/binaries/linux/mujoco210/
LOG=$VENV/mujoco-py-build.log

say() { echo "make mujoco-py: $*"; }
die() { echo "make mujoco-py: $*" >&2; exit 1; }
source "$REPO/deploy/apt_lib.sh"

[ -x "$PY" ] || die "no virtualenv at $VENV; run \`make install\` first"

# --- system packages ----------------------------------------------------------------------
py_include=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
py_dev=python$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')-dev
need=()
command -v gcc > /dev/null || need+=(gcc libc6-dev)
[ -f "$py_include/Python.h" ] || need+=("$py_dev")
command -v patchelf > /dev/null || need+=(patchelf)
if command -v dpkg-query > /dev/null; then
    for pkg in libosmesa6-dev libgl1-mesa-dev; do
        dpkg-query -W -f='${Status}' "$pkg" 2> /dev/null | grep -q "ok installed" || need+=("$pkg")
    done
else
    [ -f /usr/include/GL/osmesa.h ] || need+=(libosmesa6-dev)
    [ -f /usr/include/GL/gl.h ] || need+=(libgl1-mesa-dev)
fi
if [ ${#need[@]} -gt 0 ]; then
    if [ "$(id -u)" -eq 0 ] && command -v apt-get > /dev/null; then
        say "installing Debian packages: ${need[*]}"
        apt_install "${need[@]}"
    else
        die "missing system packages: ${need[*]}; install them (Debian: apt-get install -y \
${need[*]}) and run \`make mujoco-py\` again"
    fi
fi

# --- MuJoCo 2.1 -----------------------------------------------------------------------------
if [ ! -f "$MUJOCO/bin/libmujoco210.so" ]; then
    say "fetching MuJoCo 2.1.0 ($BINARIES from PyPI) into $MUJOCO"
    tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' EXIT
    # free-mujoco-py declares Python < 3.11; only its binaries are used, never its code.
    "$PY" -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.10 \
        -d "$tmp" "$BINARIES"
    "$PY" - "$tmp" "$MUJOCO" "$BINARIES_DIR" <<'EOF'
import glob, os, shutil, sys, zipfile

tmp, dest, prefix = sys.argv[1:]
staging = os.path.join(tmp, "mujoco210")
with zipfile.ZipFile(glob.glob(os.path.join(tmp, "*.whl"))[0]) as wheel:
    for info in wheel.infolist():
        if not info.filename.startswith(prefix) or info.is_dir():
            continue
        path = os.path.join(staging, info.filename[len(prefix):])
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with wheel.open(info) as src, open(path, "wb") as out:
            shutil.copyfileobj(src, out)
        mode = (info.external_attr >> 16) & 0o777
        os.chmod(path, mode or 0o644)
if not os.path.isfile(os.path.join(staging, "bin", "libmujoco210.so")):
    sys.exit(f"no {prefix}bin/libmujoco210.so in the wheel")
shutil.rmtree(dest, ignore_errors=True)
shutil.move(staging, dest)
EOF
fi

# --- the extra ------------------------------------------------------------------------------
say "pip install -e '.[v1]'"
(cd "$REPO" && "$PY" -m pip install --quiet -e '.[v1]')

# --- compile ------------------------------------------------------------------------------
export MUJOCO_PY_MUJOCO_PATH=$MUJOCO MUJOCO_PY_FORCE_CPU=1
generated=$("$PY" -c 'import importlib.util as u
print(u.find_spec("mujoco_py").submodule_search_locations[0])')/generated
if ! compgen -G "$generated/cymj_*_linuxcpuextensionbuilder_*.so" > /dev/null; then
    say "compiling mujoco-py's extension (once; log: $LOG)"
    if ! LD_LIBRARY_PATH=$MUJOCO/bin${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH} \
            "$PY" -c 'import mujoco_py' > "$LOG" 2>&1; then
        tail -n 30 "$LOG" >&2
        die "compiling mujoco-py failed (the whole log: $LOG)"
    fi
fi
for so in "$generated"/cymj_*_linuxcpuextensionbuilder_*.so; do
    patchelf --set-rpath "$MUJOCO/bin" "$so"
done
echo "$MUJOCO/bin" > "$generated/hercs-runpath"  # hercs.rl.envs.RUNPATH_MARK: set since the compile

# --- check ----------------------------------------------------------------------------------
env -u MUJOCO_PY_MUJOCO_PATH -u MUJOCO_PY_FORCE_CPU -u LD_LIBRARY_PATH "$PY" - <<'EOF'
from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec

spec = task_spec("push", "v1")
env = make_env(spec)
obs, _ = env.reset(seed=0)
env.step(env.action_space.sample())
env.close()
assert obs["observation"].shape == (spec.obs_dim,), obs["observation"].shape
print(f"make mujoco-py: {spec.env_id} works; run with --set task.env_version=v1")
EOF
