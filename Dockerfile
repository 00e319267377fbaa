# The image every service of docker-compose.yml runs: `hercs <command> …`.
#
# Two targets:
#   services  what docker-compose.yml runs: the router, replay, clusterer, learner, evaluator and
#             actors import neither rerun-sdk (with pyarrow), matplotlib nor imageio-ffmpeg, so
#             they are left out (`hercs view|plot|live`, `hercs eval --video|--rerun-save`
#             need the full image).
#   full      (the last stage, so the default of a plain `docker build .`): every dependency of
#             pyproject.toml, for `hercs view`, `plot`, `live` and `eval --video` too.
#
#   docker build --target services -t hercs:latest .       # what `docker compose build` does
#   docker build -t hercs:full .
#
# Build arguments; the defaults work on any machine that reaches Docker Hub, PyPI and the
# PyTorch CPU index:
#   BASE_IMAGE        any Debian-like image with python3.11 and its venv module
#   TORCH_INDEX_URL   where torch==2.13.0 comes from: the CPU build (no CUDA packages)
#   PIP_INDEX_URL, PIP_EXTRA_INDEX_URL, PIP_TRUSTED_HOST   a PyPI mirror, if any
#   PIP_NO_INDEX=1 with PIP_FIND_LINKS=/wheels   offline: every wheel from deploy/wheelhouse/
#                     (what deploy/compose_test.sh does; deploy/wheelhouse/README.md)
# The wheelhouse is copied into the deps stage only: no final image carries it.
#
# Layers are ordered for the build cache: the dependencies (a virtual environment in /opt/venv)
# depend only on pyproject.toml; hercs itself goes into /opt/hercs (on sys.path through a .pth
# file), so a code change rebuilds a few megabytes, not the 1.3 GB environment.
ARG BASE_IMAGE=python:3.11-slim

FROM ${BASE_IMAGE} AS base
ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/venv \
    PATH=/opt/hercs/bin:/opt/venv/bin:$PATH

# -- deps: the services' dependencies ------------------------------------------------------------
FROM base AS deps
ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu
ARG PIP_INDEX_URL
ARG PIP_EXTRA_INDEX_URL
ARG PIP_TRUSTED_HOST
ARG PIP_NO_INDEX
ARG PIP_FIND_LINKS
RUN python3 -m venv /opt/venv \
 && echo /opt/hercs \
      > "$(python3 -c 'import sysconfig; print(sysconfig.get_path("purelib"))')/hercs.pth"
COPY deploy/wheelhouse /wheels

# torch first, pinned, from the CPU index: a later unpinned resolution would pull several GB of
# CUDA packages; the project's range (>=2.13,<2.14) is then already satisfied. (With
# PIP_NO_INDEX=1 the index is ignored and the CPU wheel comes from the wheelhouse.) Its C++ test
# binaries (torch/test, torch/bin; 130 MB) are dropped; torch_shm_manager stays.
RUN pip install torch==2.13.0 --index-url ${TORCH_INDEX_URL} \
 && torch=$(python3 -c 'import sysconfig; print(sysconfig.get_path("purelib"))')/torch \
 && rm -rf "$torch/test" \
 && find "$torch/bin" -type f ! -name torch_shm_manager -delete

# pyproject.toml's dependencies less the view/plot/video ones.
WORKDIR /src
COPY pyproject.toml ./
RUN python3 -c "import re, tomllib; \
deps = tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']; \
print('\n'.join(d for d in deps if re.split(r'[<>=!~;\[ ]', d)[0].lower() \
                not in ('rerun-sdk', 'matplotlib', 'imageio-ffmpeg')))" > services.txt \
 && pip install -r services.txt

# -- build: hercs itself, without dependencies, into /opt/hercs ---------------------------------
FROM deps AS build
ARG PIP_INDEX_URL
ARG PIP_EXTRA_INDEX_URL
ARG PIP_TRUSTED_HOST
ARG PIP_NO_INDEX
ARG PIP_FIND_LINKS
COPY README.md ./
COPY hercs hercs
RUN pip install --no-deps --target /opt/hercs .

# -- services: what docker-compose.yml runs -----------------------------------------------------
FROM base AS services
COPY --from=deps /opt/venv /opt/venv
COPY --from=build /opt/hercs /opt/hercs
COPY deploy/compose-entrypoint.sh /usr/local/bin/hercs-compose
# Run directories go to /runs (a volume in docker-compose.yml).
WORKDIR /runs
ENTRYPOINT ["hercs"]
CMD ["--help"]

# -- deps-full: every dependency of pyproject.toml ----------------------------------------------
FROM deps AS deps-full
ARG PIP_INDEX_URL
ARG PIP_EXTRA_INDEX_URL
ARG PIP_TRUSTED_HOST
ARG PIP_NO_INDEX
ARG PIP_FIND_LINKS
RUN python3 -c "import tomllib; \
print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" \
      > all.txt \
 && pip install -r all.txt

# -- full ---------------------------------------------------------------------------------------
FROM base AS full
COPY --from=deps-full /opt/venv /opt/venv
COPY --from=build /opt/hercs /opt/hercs
COPY deploy/compose-entrypoint.sh /usr/local/bin/hercs-compose
WORKDIR /runs
ENTRYPOINT ["hercs"]
CMD ["--help"]
