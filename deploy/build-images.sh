#!/usr/bin/env bash
# Build robobpp's images on a host that reaches no image registry: only Debian's package mirror and the Python
# package index, from the host (containers reach neither).
#
#   sudo deploy/build-images.sh            # then: docker compose -f docker-compose.yml -f deploy/compose.debian.yml up -d
#
# 1. robobpp-debian:bookworm  a Debian rootfs made by debootstrap (python3.11, postgresql-15, redis-server),
#                             `docker import`ed; the base of the three images below (built once, then reused).
# 2. wheels                   `pip wheel` of robobpp[all] on the host at the versions of requirements/ci.txt, and
#                             the packsim wheel the datasets are read from (containers cannot download it).
# 3. robobpp:debian           deploy/Dockerfile.debian: the project installed from those wheels (--network none).
#    robobpp-postgres:debian  deploy/postgres/: Debian's PostgreSQL 15, the official image's variables.
#    robobpp-redis:debian     deploy/redis/: Debian's Redis 7.
#
# Needs root, Debian's docker.io and debootstrap packages, a running daemon (deploy/dockerd.sh start) and a
# Python with pip on the host of the images' exact version (Debian bookworm's python3, 3.11.2).
# Environment: PYTHON (default /usr/bin/python3), DEBIAN_MIRROR, ROBOBPP_IMAGE_TAG (default debian),
# ROBOBPP_BUILD_DIR (default deploy/.build), REBUILD_BASE=1 (debootstrap again).
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-/usr/bin/python3}"
MIRROR="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
TAG="${ROBOBPP_IMAGE_TAG:-debian}"
BUILD="${ROBOBPP_BUILD_DIR:-deploy/.build}"
BASE=robobpp-debian:bookworm
SUITE=bookworm
LABEL=org.robobpp.build=deploy/build-images.sh
PACKAGES=python3,python3-venv,libgomp1,curl,ca-certificates,postgresql-15,redis-server,redis-tools

say() { printf "== [%4d s] %s\n" "$(( $(date +%s) - started ))" "$*"; }
started=$(date +%s)

docker info >/dev/null 2>&1 || { echo "no Docker daemon answers (start one: deploy/dockerd.sh start)" >&2; exit 1; }

if [ -n "${REBUILD_BASE:-}" ] || ! docker image inspect "$BASE" >/dev/null 2>&1; then
  command -v debootstrap >/dev/null || { echo "debootstrap not found (apt-get install debootstrap)" >&2; exit 1; }
  say "debootstrap $SUITE ($PACKAGES) from $MIRROR"
  rootfs="$BUILD/rootfs"
  rm -rf "$rootfs"
  mkdir -p "$rootfs"
  debootstrap --variant=minbase --include="$PACKAGES" "$SUITE" "$rootfs" "$MIRROR" >"$BUILD/debootstrap.log" 2>&1 \
    || { tail -n 20 "$BUILD/debootstrap.log" >&2; exit 1; }
  # Not in an image: downloaded packages, docs and translations, the cluster the package's postinst made
  # (the postgres image initialises its own in its volume), and the apt lists.
  rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/* "$rootfs"/usr/share/doc/* \
    "$rootfs"/usr/share/man/* "$rootfs"/usr/share/locale/* "$rootfs"/var/lib/postgresql/15 "$rootfs"/etc/postgresql/15
  say "docker import $BASE"
  tar -C "$rootfs" --numeric-owner -c . | docker import \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8' \
    --change 'CMD ["/bin/bash"]' - "$BASE" >/dev/null
  rm -rf "$rootfs"
else
  say "$BASE exists (REBUILD_BASE=1 rebuilds it)"
fi

# pip picks wheels by the running interpreter's version (markers such as python_full_version < "3.11.3"),
# so the wheels are built by a Python of exactly the images' version: Debian bookworm's own on a bookworm host.
want="$(docker run --rm --network none "$BASE" python3 -c 'import platform; print(platform.python_version())')"
have="$("$PYTHON" -c 'import platform; print(platform.python_version())')"
[ "$want" = "$have" ] || { echo "$PYTHON is Python $have; the images run $want: set PYTHON to a $want with pip" >&2; exit 1; }

say "wheels of robobpp[all] (requirements/ci.txt) into $BUILD/wheels"
# Afresh each time (pip's cache makes it quick), so the directory holds exactly one resolved set.
rm -rf "$BUILD/wheels" "$BUILD/data"
mkdir -p "$BUILD/wheels" "$BUILD/data"
"$PYTHON" -m pip wheel -q -c requirements/ci.txt -w "$BUILD/wheels" ".[all]" setuptools wheel
# The image installs the project itself editable from its source (migrations/ sits next to the package).
rm -f "$BUILD"/wheels/robobpp-*.whl
packsim="$(sed -n 's/^PACKSIM_REQUIREMENT = "\(.*\)"$/\1/p' robobpp/datasets/sources.py)"
"$PYTHON" -m pip download -q --no-deps -d "$BUILD/data" "$packsim"

say "robobpp:$TAG"
docker build -q --force-rm --network none -f deploy/Dockerfile.debian --build-arg BASE="$BASE" --label "$LABEL" \
  --label "org.robobpp.source=$("$PYTHON" deploy/source_hash.py)" \
  --build-arg WHEELS="$BUILD/wheels" --build-arg DATA="$BUILD/data" -t "robobpp:$TAG" . >/dev/null
say "robobpp-postgres:$TAG, robobpp-redis:$TAG"
docker build -q --force-rm --network none -f deploy/postgres/Dockerfile --build-arg BASE="$BASE" --label "$LABEL" -t "robobpp-postgres:$TAG" deploy/postgres >/dev/null
docker build -q --force-rm --network none -f deploy/redis/Dockerfile --build-arg BASE="$BASE" --label "$LABEL" -t "robobpp-redis:$TAG" deploy/redis >/dev/null

# A rebuild moves each tag to the new image and leaves the old one dangling (<none>, 1 GB for robobpp:debian):
# remove the dangling images this script built, no other image (a container still using one keeps it).
say "docker image prune (dangling images labelled $LABEL)"
docker image prune -f --filter "label=$LABEL" >/dev/null
docker image ls --format '{{.Repository}}:{{.Tag}}  {{.Size}}' | grep -E "^(robobpp[^:]*:$TAG|$BASE) " || true
say "done"
