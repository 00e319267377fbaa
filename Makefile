# Two commands on a fresh machine: `make run` and `make test`. Each creates .venv on its own.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.installed

.PHONY: run test lint proto install clean

$(PY):
	$(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)

# torch goes in first, pinned to the local CPU wheel: a later, unpinned resolution of torch
# would pull several GB of CUDA packages. The project's own range (>=2.13,<2.14) is then
# already satisfied.
$(STAMP): pyproject.toml | $(PY)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet torch==2.13.0
	$(PIP) install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# A short real run: router, replay, clusterer, learner, evaluator and two actors as separate
# processes over Zenoh, FetchReach with HER-CS for 3 epochs; prints where the run directory is.
run: $(STAMP)
	$(VENV)/bin/hercs up --task reach --method her-cs --epochs 3 --actors 2

test: lint
	$(PY) -m pytest -q tests

# ruff, the layer contracts (import-linter, see pyproject.toml) and the type check.
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports
	$(VENV)/bin/mypy

# Regenerate proto/hercs_pb2.py(.pyi) from proto/hercs.proto with the pinned grpcio-tools.
proto: $(STAMP)
	cd proto && ../$(PY) -m grpc_tools.protoc -I. --python_out=. --pyi_out=. hercs.proto

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
