# robobpp: one image for the API server and the Celery workers (the command picks the role).
# Build:  docker build -t robobpp .        Run: see docker-compose.yml and docs/deploy.md
FROM python:3.11-slim AS base

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# libgomp: OMPL's wheel links it; curl: the container health check. pybullet and ompl ship manylinux wheels.
RUN apt-get update \
 && apt-get install -y --no-install-recommends libgomp1 curl \
 && rm -rf /var/lib/apt/lists/*

# An unprivileged user owns the data directories; the services never run as root.
RUN useradd --create-home --uid 10001 robobpp
WORKDIR /app

# Editable: the code runs from /app, where robobpp/db/migrate.py finds migrations/ next to the package (a
# plain install copies the package alone into site-packages and the server cannot migrate at start).
COPY pyproject.toml README.md ./
COPY robobpp ./robobpp
COPY migrations ./migrations
COPY alembic.ini ./
COPY setup.py ./
# gcc for the compiled kernels (robobpp/scoring/_kernels.c), removed once they are built
RUN apt-get update \
 && apt-get install -y --no-install-recommends gcc libc6-dev \
 && pip install -e ".[all]" \
 && apt-get purge -y gcc libc6-dev && apt-get autoremove -y && rm -rf /var/lib/apt/lists/* \
 && python -c "import robobpp.scoring._kernels" \
 && mkdir -p /app/datasets_private /data \
 && chown -R robobpp:robobpp /app/datasets_private /data

USER robobpp
# Server state (SQLite in single-machine mode), the data cache (fetched RoboBPP files) and the private split
# live on volumes.
ENV ROBOBPP_STATE_DIR=/data \
    ROBOBPP_DATA_DIR=/data/datasets-cache \
    ROBOBPP_PRIVATE_DIR=/app/datasets_private
VOLUME ["/data", "/app/datasets_private"]

EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=120s --retries=3 \
  CMD curl -fsS http://127.0.0.1:8000/healthz || exit 1

# Default role: the API server. The worker service overrides the command with `robobpp worker`.
CMD ["robobpp", "serve", "--host", "0.0.0.0", "--port", "8000"]
