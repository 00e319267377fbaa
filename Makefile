# Two commands on a fresh machine: `make run` and `make test`. Each creates .venv on its own.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.installed

.PHONY: run test test-full studies-check lint proto install clean compose-test compose-clean figures mujoco-py slurm \
	slurm-test netfault-tools browser-tools

$(PY):
	$(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)

# torch goes in first, the CPU build from PyTorch's wheel index: PyPI's torch for Linux is
# the CUDA build and pulls several GB of nvidia-* packages. With a GPU, pick a CUDA index:
#   make test TORCH_INDEX=https://download.pytorch.org/whl/cu128
# The project's own range (torch>=2.13,<2.14) is then already satisfied. PIP_TORCH_ARGS may
# add e.g. --retries 0 where that index is unreachable and a local wheel serves (CI here).
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu
PIP_TORCH_ARGS ?=
$(STAMP): pyproject.toml | $(PY)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet torch==2.13.0 --index-url $(TORCH_INDEX) $(PIP_TORCH_ARGS)
	$(PIP) install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# The authors' environment, Fetch*-v1 on mujoco-py and MuJoCo 2.1 (--set task.env_version=v1):
# Debian's compiler and OSMesa/GL headers when root and missing, MuJoCo 2.1 from PyPI's
# free-mujoco-py wheel into .venv/mujoco210, the `v1` extra, mujoco-py's one-time compile and a
# check (deploy/install_mujoco_py.sh). About a minute on a fresh machine; a second run checks.
mujoco-py: $(STAMP)
	VENV=$(abspath $(VENV)) bash deploy/install_mujoco_py.sh

# A real Slurm for tests/integration/test_slurm.py: Debian's slurm-wlm, slurmdbd, munge and
# mariadb-server when root and missing (deploy/install_slurm.sh; nothing is started). Without
# them the test prints "SKIPPED: <reason>".
slurm:
	bash deploy/install_slurm.sh

# What tests/fault/test_network_faults.py, bench/faults/net_faults.py and bench/faults/chaos.py
# build a network between namespaced hosts with: Debian's iproute2 (ip, tc) and iptables when
# root and missing (deploy/install_netfault_tools.sh; nothing is configured). Without them, or
# without root, the tests print "SKIPPED: <reason>".
netfault-tools:
	bash deploy/install_netfault_tools.sh

# Headless Chromium for the browser test of the web viewer (tests/integration/test_browser_views.py).
browser-tools:
	bash deploy/install_browser.sh

# Only the Slurm test (a cluster of two namespaced nodes; 6 to 8 minutes on 2 cores, docs/CLUSTER.md §8).
slurm-test: $(STAMP) slurm
	$(PY) -m pytest -q -s tests/integration/test_slurm.py

# A short real run: router, replay, clusterer, learner, evaluator and two actors as separate
# processes over Zenoh, FetchPush with HER-CS for 4 epochs (a few minutes on 2 cores): the
# clusterer fits its first model within epoch 1 (FetchPush fails often at first, so failed
# goals come fast; measured 2026-11-28, twice: metrics.csv's cluster_model_version 1, 2, 3, 4
# after epochs 1-4), so each epoch line shows the clusters and the last line the
# `hercs view RUN_DIR` that draws them.
run: $(STAMP)
	$(VENV)/bin/hercs up --task push --method her-cs --epochs 4 --actors 2

# `make test`: every test but the long scenarios (marked `full`) and the committed documents
# (`docs_check`). TEST_WORKERS=N spreads it over N pytest-xdist workers, a file (or a package,
# tests/conftest.py) whole on each; on 2 busy cores its tests compute more than they wait and
# workers made it slower (README, "Development": what each command checks, how long it takes).
# --durations: the 25 slowest tests, so that the suite's time has names.
TEST_WORKERS ?= 0
# `make test-full` one scenario at a time, as CI has always run them: pairing them on 2 workers
# paid on one pair (rejoin beside the goal env's learning run, 167 s against 189 s) but Slurm
# beside the namespaced network faults is untried (FULL_WORKERS=2 to try).
FULL_WORKERS ?= 0
test: lint
	$(PY) -m pytest -q --durations=25 -n $(TEST_WORKERS) --dist loadfile \
		-m "not full and not docs_check" tests

# What `make test` leaves out, and only that: every test that took 15 s or more alone in a
# clean clone (whole-run scenarios, benchmarks' quick modes), the Slurm cluster, network
# faults between namespaced hosts, the chaos soak, the runs that must learn (FetchReach, a goal env, a
# poisoned run, SB3), and the committed reports (`make studies-check`'s tests). .ci/run runs
# both, so that together they are the whole suite, each test once.
test-full: $(STAMP)
	$(PY) -m pytest -q --durations=25 -n $(FULL_WORKERS) --dist loadfile \
		-m "full or docs_check" tests

# The committed reports and figures against the committed runs (the tests marked docs_check: a
# finding or a figure is checked where it is made, not as a contract of the code). Run it after
# `make figures` or a study; .ci/run runs it after `make test`.
studies-check: $(STAMP)
	$(PY) -m pytest -q -m docs_check tests

# docker-compose.yml for real: a private Docker engine (installed from Debian and started in its
# own network namespace if none runs), an offline image build, a short FetchReach run with 4
# actors, checks, teardown. Prints "SKIPPED: <reason>" and succeeds where no engine can run
# (not root, no apt-get). Caches under /var/cache/hercs-ci (deploy/compose_test.sh).
compose-test: $(STAMP)
	bash deploy/compose_test.sh

# Delete compose-test's caches (base image tarball, wheelhouse, the engine's data root).
compose-clean:
	bash deploy/compose_test.sh clean

# ruff, the layer contracts (import-linter, see pyproject.toml) and the type check.
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports
	$(VENV)/bin/mypy

# Redraw the figures that are drawn from committed runs (`make studies-check` checks them).
figures: $(STAMP)
	$(VENV)/bin/hercs plot --figure 2 docs/results/runs/*/ -o docs/results/fig2.png --table docs/results/fig2.md > /dev/null
	$(PY) -m studies.schedule_effect > /dev/null
	$(PY) -m studies.claims > /dev/null

# Regenerate hercs/proto/hercs_pb2.py(.pyi) from hercs/proto/hercs.proto with the pinned grpcio-tools.
proto: $(STAMP)
	cd hercs/proto && ../../$(PY) -m grpc_tools.protoc -I. --python_out=. --pyi_out=. hercs.proto

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
