#!/usr/bin/env bash
# The GPU checks of a lent CUDA machine in one go (docs/PERFORMANCE.md §10): the CUDA tests, the
# learner's update rate (bench.perf.learner_cuda: eager against the captured CUDA graph) and the
# actors one GPU learner feeds (bench.perf.learner_feed --device cuda).
#
#   bench/perf/gpu_check.sh OUT [SECONDS]
#
# Run from the repository root on the GPU machine, whose python3 has torch with CUDA. Packages
# that machine lacks come as wheels or zips in .whl/, installed into a temporary folder of this
# check's own. Results land in a work folder, packed into OUT/gpu_check.tar.gz after every
# step, so a run cut off by the machine's time limit still returns what it finished. SECONDS
# (default 540) is the time the whole check may take; each step gets at most what is left of
# it. Exits 1 if a step failed or was skipped.
set -u
shopt -s nullglob
OUT=${1:?usage: bench/perf/gpu_check.sh OUT [SECONDS]}
DEADLINE=$(( $(date +%s) + ${2:-540} ))
TMP=$(mktemp -d)
WORK=$TMP/gpu_check
mkdir -p "$WORK" "$OUT"
export PYTHONUNBUFFERED=1
FAILED=0
pack() { tar -czf "$OUT/gpu_check.tar.gz" -C "$TMP" gpu_check; }
left() { echo $(( DEADLINE - $(date +%s) - 20 )); }
step() {  # step NAME SECONDS COMMAND...: at most SECONDS (or what is left), output in NAME.txt
    local name=$1 limit=$2; shift 2
    if (( $(left) < limit )); then limit=$(left); fi
    if (( limit < 30 )); then
        echo "$name skipped: ${limit}s left" | tee -a "$WORK/status.txt"; FAILED=1; return
    fi
    echo "== $name (at most ${limit}s): $*"
    timeout -k 10 "$limit" "$@" > "$WORK/$name.txt" 2>&1
    local rc=$?
    echo "$name rc $rc" | tee -a "$WORK/status.txt"
    (( rc == 0 )) || FAILED=1
    tail -n 25 "$WORK/$name.txt"
    pack
}

if [ -d .whl ]; then  # the packages this machine lacks, into a folder of this check's own
    wheels=(.whl/*.whl) zips=(.whl/*.zip)
    if (( ${#wheels[@]} )); then
        python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
            --target "$TMP/site" "${wheels[@]}" || exit 3
    fi
    for z in "${zips[@]}"; do python3 -m zipfile -e "$z" "$TMP/site" || exit 3; done
    export PYTHONPATH="$TMP/site${PYTHONPATH:+:$PYTHONPATH}"
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"

{ nvidia-smi -L; nproc; lscpu | grep "Model name"; git rev-parse --short HEAD 2>/dev/null
  python3 -c "import torch, mujoco, zenoh, gymnasium_robotics; print('torch', torch.__version__,
torch.cuda.is_available(), torch.cuda.get_device_name(0), 'mujoco', mujoco.__version__)"
} > "$WORK/machine.txt" 2>&1
cat "$WORK/machine.txt"
step imports 60 python3 -c "import hercs.apps.cli.main, hercs.learner.ddpg, hercs.replay_service, \
hercs.clusterer, hercs.actors, hercs.run.runlog.writer, zenoh, zstandard
from hercs.rl.envs import make_env; from hercs.rl.task_registry import task_spec
print(make_env(task_spec('push')).reset(seed=0)[0]['observation'].shape)"
step pytest 180 python3 -m pytest -p no:cacheprovider -q tests/unit/learner/test_learner_cuda_graph.py \
    tests/unit/learner/test_learner_device.py tests/bench/perf/test_learner_cuda_bench.py
step learner_cuda 240 python3 -m bench.perf.learner_cuda --out "$WORK"
step learner_feed 100000 python3 -m bench.perf.learner_feed --device cuda --epochs 4 \
    --out "$WORK"
cat "$WORK/status.txt"
exit $FAILED
