# The image every service of docker-compose.yml runs: `hercs <command> …`.
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# torch first, pinned, from the CPU index: a later unpinned resolution would pull several GB of
# CUDA packages; the project's range (>=2.13,<2.14) is then already satisfied.
RUN pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu

WORKDIR /opt/hercs
COPY pyproject.toml README.md ./
COPY proto proto
COPY hercs hercs
COPY actors actors
COPY learner learner
COPY replay_service replay_service
COPY clusterer clusterer
COPY apps apps
RUN pip install .

# Run directories go to /runs (a volume in docker-compose.yml).
WORKDIR /runs
ENTRYPOINT ["hercs"]
CMD ["--help"]
