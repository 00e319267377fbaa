"""Every service limits its numerics to one thread (hercs.net.threads): checked in a fresh
interpreter, as a service process starts, so this test process keeps its own pools."""

from __future__ import annotations

import json
import subprocess
import sys

PROBE = """
import json, numpy, torch
from threadpoolctl import threadpool_info
from hercs.net.threads import single_threaded_numerics
before = max(i["num_threads"] for i in threadpool_info())
single_threaded_numerics()
print(json.dumps({"pools": [i["num_threads"] for i in threadpool_info()],
                  "torch": torch.get_num_threads(), "before": before}))
"""


def test_blas_pools_and_torch_run_on_one_thread_after_the_call() -> None:
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                          timeout=120, env={"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2",
                                            "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    assert seen["before"] == 2, "the probe starts with a 2-thread BLAS pool"
    assert seen["pools"] and set(seen["pools"]) == {1}
    assert seen["torch"] == 1
