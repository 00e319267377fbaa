#!/usr/bin/env bash
# The GPU checks of a lent CUDA machine in one go (docs/PERFORMANCE.md §10): the CUDA tests, the
# learner's update rate (bench.perf.learner_cuda: eager against the captured CUDA graph) and the
# actors one GPU learner feeds (bench.perf.learner_feed --device cuda).
#
#   bench/perf/gpu_check.sh OUT [SECONDS]
#
# Run from the repository root on the GPU machine, whose python3 has torch with CUDA. Packages
# that machine lacks come as wheels or zips in .whl/ (installed into /tmp/site). Everything lands
# in a work folder, packed into OUT/gpu_check.tar.gz after every step, so a run cut off by the
# machine's time limit still returns what it finished. SECONDS (default 540) is the time the
# whole check may take; the last step gets what is left of it.
set -u
OUT=${1:?usage: bench/perf/gpu_check.sh OUT [SECONDS]}
DEADLINE=$(( $(date +%s) + ${2:-540} ))
WORK=$(mktemp -d)/gpu_check
mkdir -p "$WORK" "$OUT"
export PYTHONUNBUFFERED=1
pack() { tar -czf "$OUT/gpu_check.tar.gz" -C "$(dirname "$WORK")" gpu_check; }
step() {  # step NAME SECONDS COMMAND...: its output in NAME.txt, its exit status noted
    local name=$1 limit=$2; shift 2
    echo "== $name (at most ${limit}s): $*"
    timeout -k 10 "$limit" "$@" > "$WORK/$name.txt" 2>&1
    echo "$name rc $?" | tee -a "$WORK/status.txt"
    tail -n 25 "$WORK/$name.txt"
    pack
}
left() { echo $(( DEADLINE - $(date +%s) - 20 )); }

if [ -d .whl ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site .whl/*.whl || exit 3
    for z in .whl/*.zip; do python3 -m zipfile -e "$z" /tmp/site || exit 3; done
fi
export PYTHONPATH="$PWD:/tmp/site${PYTHONPATH:+:$PYTHONPATH}"

{ nvidia-smi -L; nproc; lscpu | grep "Model name"; git rev-parse --short HEAD 2>/dev/null
  python3 -c "import torch, mujoco, zenoh, gymnasium_robotics; print('torch', torch.__version__,
torch.cuda.is_available(), torch.cuda.get_device_name(0), 'mujoco', mujoco.__version__)"
} > "$WORK/machine.txt" 2>&1
cat "$WORK/machine.txt"
step imports 60 python3 -c "import hercs.apps.cli, hercs.learner.ddpg, hercs.replay_service, \
hercs.clusterer, hercs.actors, hercs.run.runlog.writer, zenoh, zstandard
from hercs.rl.envs import make_env; from hercs.rl.task_registry import task_spec
print(make_env(task_spec('push')).reset(seed=0)[0]['observation'].shape)"
step pytest 180 python3 -m pytest -p no:cacheprovider -q tests/unit/learner/test_learner_cuda_graph.py \
    tests/unit/learner/test_learner_device.py tests/bench/perf/test_learner_cuda_bench.py
step learner_cuda 240 python3 -m bench.perf.learner_cuda --out "$WORK"
step learner_feed "$(left)" python3 -m bench.perf.learner_feed --device cuda --epochs 4 \
    --out "$WORK"
cat "$WORK/status.txt"
