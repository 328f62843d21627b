#!/usr/bin/env bash
# Container engine for `make test-docker`: make one available, build mimic:latest, run the tests.
#
#   tests/docker/engine.sh            # prepare the engine + image, then run tests/docker (pytest)
#   tests/docker/engine.sh prepare    # only prepare (prints DOCKER_HOST to use)
#
# MIMIC_ENGINE picks the engine; unset: podman when installed, else a Docker engine that answers,
# else podman installed as root. MIMIC_ENGINE=podman installs what is missing, idempotently and
# fast when present:
#   1. podman, runc, debootstrap (apt-get, as root);
#   2. tests/docker/containers.conf via CONTAINERS_CONF (ulimits this sandbox accepts, runc);
#   3. a base image without a registry: debootstrap bookworm from the apt mirror, imported as
#      localhost/debian-py:bookworm (skipped when it exists);
#   4. mimic:latest from deploy/Dockerfile with BASE_IMAGE=localhost/debian-py:bookworm (layer cache);
#   5. `podman system service` on a socket of its own, stopped again at the end.
# MIMIC_ENGINE=docker uses the Docker engine already running (DOCKER_HOST or the default
# socket) and the normal python:3.11-slim base: a laptop with Docker runs the same tests.
# Every step prints its duration; a failing step says which one and why.
set -euo pipefail

REPO="$(cd "$(dirname "$0")/../.." && pwd)"
cd "$REPO"
if [ -n "${MIMIC_ENGINE:-}" ]; then
  ENGINE="$MIMIC_ENGINE"
elif command -v podman >/dev/null; then
  ENGINE=podman
elif command -v docker >/dev/null && docker info >/dev/null 2>&1; then
  ENGINE=docker
else
  ENGINE=podman
fi
BASE_IMAGE="${MIMIC_BASE_IMAGE:-localhost/debian-py:bookworm}"
IMAGE="${MIMIC_IMAGE:-mimic:latest}"
STATE_DIR="${MIMIC_PODMAN_DIR:-/tmp/mimic-podman}"
SOCK="$STATE_DIR/podman.sock"
PY="${PYTHON:-$REPO/.venv/bin/python}"
T_ALL=$(date +%s.%N)

step_start() { STEP="$1"; T0=$(date +%s.%N); echo "[test-docker] $STEP ..." >&2; }
step_done() {
  local dt
  dt=$(awk -v a="$T0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
  echo "[test-docker] $STEP: ${1:-done} in ${dt} s" >&2
  echo "$STEP|${1:-done}|$dt" >> "$STATE_DIR/timings"
}
die() { echo "[test-docker] FAILED at step '${STEP:-setup}': $*" >&2; exit 1; }
trap 'rc=$?; [ $rc -ne 0 ] && echo "[test-docker] FAILED at step ${STEP:-setup} (exit $rc); see the output above" >&2' EXIT

mkdir -p "$STATE_DIR"
: > "$STATE_DIR/timings"

apt_mirror() {  # the Debian mirror apt already uses here
  local m=""
  if [ -f /etc/apt/sources.list ]; then
    m=$(awk '$1 == "deb" { for (i = 2; i <= NF; i++) if ($i ~ /^https?:/) { print $i; exit } }' /etc/apt/sources.list)
  fi
  if [ -z "$m" ] && ls /etc/apt/sources.list.d/*.sources >/dev/null 2>&1; then
    m=$(awk '$1 == "URIs:" && $2 !~ /security/ { print $2; exit }' /etc/apt/sources.list.d/*.sources)
  fi
  echo "${m:-http://deb.debian.org/debian}"
}

install_podman() {
  step_start "install podman"
  if command -v podman >/dev/null && command -v runc >/dev/null && command -v debootstrap >/dev/null; then
    step_done "present ($(podman --version))"
    return
  fi
  [ "$(id -u)" = 0 ] || die "podman, runc or debootstrap missing and not root: install them (apt-get install podman runc debootstrap) or use MIMIC_ENGINE=docker"
  command -v apt-get >/dev/null || die "no apt-get: install podman, runc and debootstrap by hand, or use MIMIC_ENGINE=docker"
  export DEBIAN_FRONTEND=noninteractive
  # The mirror may drop a connection: one retry of the download, never of a broken install.
  apt-get update -qq || { sleep 5; apt-get update -qq; } || die "apt-get update failed"
  apt-get install -y -qq podman runc debootstrap >"$STATE_DIR/apt.log" 2>&1 \
    || { sleep 5; apt-get install -y -qq podman runc debootstrap >>"$STATE_DIR/apt.log" 2>&1; } \
    || { tail -30 "$STATE_DIR/apt.log" >&2; die "apt-get install podman runc debootstrap failed"; }
  step_done "installed ($(podman --version))"
}

base_image() {
  step_start "base image $BASE_IMAGE"
  if podman image exists "$BASE_IMAGE"; then
    step_done "cached"
    return
  fi
  local dir mirror
  dir=$(mktemp -d /var/tmp/mimic-debootstrap.XXXXXX)
  mirror=$(apt_mirror)
  # The system libraries deploy/Dockerfile installs come in here already: one apt run, not two.
  debootstrap --variant=minbase --include=python3,python3-venv,python3-pip,ca-certificates,libgomp1,libopengl0,libegl1 \
    bookworm "$dir" "$mirror" >"$STATE_DIR/debootstrap.log" 2>&1 \
    || { tail -30 "$STATE_DIR/debootstrap.log" >&2; rm -rf "$dir"; die "debootstrap bookworm from $mirror failed"; }
  tar -C "$dir" -c . | podman import - "$BASE_IMAGE" >/dev/null || { rm -rf "$dir"; die "podman import failed"; }
  rm -rf "$dir"
  step_done "debootstrap from $mirror"
}

build_image() {
  step_start "build $IMAGE"
  local log="$STATE_DIR/build.log"
  if [ "$ENGINE" = podman ]; then
    # --network host + the host's CA store: pip inside the build reaches the package index as the host does.
    podman build --network host --volume /etc/ssl/certs:/etc/ssl/certs:ro \
      --build-arg BASE_IMAGE="$BASE_IMAGE" -t "$IMAGE" -f deploy/Dockerfile . >"$log" 2>&1 \
      || { tail -40 "$log" >&2; die "podman build failed (full log: $log)"; }
  else
    docker build -t "$IMAGE" -f deploy/Dockerfile . >"$log" 2>&1 \
      || { tail -40 "$log" >&2; die "docker build failed (full log: $log)"; }
  fi
  step_done "built"
}

start_service() {
  step_start "podman system service"
  if [ -S "$SOCK" ] && curl -sf --unix-socket "$SOCK" http://d/_ping >/dev/null 2>&1; then
    step_done "already listening on $SOCK"
    return
  fi
  rm -f "$SOCK"
  podman system service --time=0 "unix://$SOCK" >"$STATE_DIR/service.log" 2>&1 &
  echo $! > "$STATE_DIR/service.pid"
  STARTED_SERVICE=$!
  for _ in $(seq 100); do
    curl -sf --unix-socket "$SOCK" http://d/_ping >/dev/null 2>&1 && break
    kill -0 "$STARTED_SERVICE" 2>/dev/null || { cat "$STATE_DIR/service.log" >&2; die "podman system service exited"; }
    sleep 0.1
  done
  curl -sf --unix-socket "$SOCK" http://d/_ping >/dev/null 2>&1 || die "podman system service did not answer on $SOCK within 10 s"
  step_done "listening on $SOCK"
}

stop_service() {
  if [ -n "${STARTED_SERVICE:-}" ] && kill -0 "$STARTED_SERVICE" 2>/dev/null; then
    kill "$STARTED_SERVICE" 2>/dev/null || true
    wait "$STARTED_SERVICE" 2>/dev/null || true
    rm -f "$STATE_DIR/service.pid"
  fi
}

prepare() {
  [ -x "$PY" ] || die "$PY missing: run make setup first"
  case "$ENGINE" in
    podman)
      command -v curl >/dev/null || die "curl missing (used to ping the podman socket)"
      install_podman
      export CONTAINERS_CONF="$REPO/tests/docker/containers.conf"
      base_image
      build_image
      start_service
      export DOCKER_HOST="unix://$SOCK"
      ;;
    docker)
      step_start "docker engine"
      docker info >/dev/null 2>&1 || die "no Docker engine answers (docker info failed): start Docker or use MIMIC_ENGINE=podman"
      step_done "reachable"
      build_image
      ;;
    *) die "MIMIC_ENGINE must be podman or docker, not '$ENGINE'" ;;
  esac
  export MIMIC_ENGINE="$ENGINE" MIMIC_DOCKER_REQUIRED=1
}

prepare
if [ "${1:-run}" = prepare ]; then
  echo "DOCKER_HOST=${DOCKER_HOST:-}"
  exit 0
fi
trap 'rc=$?; stop_service; [ $rc -ne 0 ] && echo "[test-docker] FAILED at step ${STEP:-setup} (exit $rc); see the output above" >&2' EXIT
step_start "container tests"
echo "[test-docker] engine $ENGINE, DOCKER_HOST=${DOCKER_HOST:-default}" >&2
rc=0
"$PY" -m pytest -p no:cacheprovider -m docker tests/docker "${@:2}" || rc=$?
# The figures of every step (also on failure: they say how far it got).
latest=$(ls -t runs/*_docker.json 2>/dev/null | head -1 || true)
[ -n "$latest" ] && { echo "[test-docker] figures ($latest):" >&2; cat "$latest" >&2; echo >&2; }
[ $rc -eq 0 ] || die "container tests failed (pytest exit $rc)"
step_done "passed"
awk -v a="$T_ALL" -v b="$(date +%s.%N)" 'BEGIN { printf "[test-docker] total %.1f s\n", b - a }' >&2
