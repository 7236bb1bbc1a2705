#!/usr/bin/env bash
# Start or stop a Docker daemon that leaves the host's firewall and network alone.
#
#   deploy/dockerd.sh start    # dockerd --iptables=false --ip-masq=false --bridge=none, waits until it answers
#   deploy/dockerd.sh stop     # stops the daemon this script started (and its containerd)
#   deploy/dockerd.sh status
#
# For hosts where the firewall must not change (no NAT rules, no docker0 bridge): containers then run with host
# networking only (deploy/compose.host-network.yml). Images persist in DOCKER_DATA_ROOT between starts.
# Needs root and Debian's docker.io package.
set -euo pipefail

DATA_ROOT="${DOCKER_DATA_ROOT:-/var/lib/docker}"
RUN_DIR="${DOCKER_RUN_DIR:-/run/robobpp-dockerd}"
PIDFILE="$RUN_DIR/dockerd.pid"
LOG="$RUN_DIR/dockerd.log"

answers() { docker info >/dev/null 2>&1; }

case "${1:-}" in
  start)
    if answers; then echo "a Docker daemon already answers; using it"; exit 0; fi
    command -v dockerd >/dev/null || { echo "dockerd not found (apt-get install docker.io)" >&2; exit 1; }
    [ "$(id -u)" = 0 ] || { echo "starting dockerd needs root" >&2; exit 1; }
    mkdir -p "$RUN_DIR" "$DATA_ROOT"
    # setsid: the daemon outlives this shell but not a `stop`; its own log says why it failed to start.
    setsid dockerd --iptables=false --ip-masq=false --bridge=none --data-root "$DATA_ROOT" \
      --pidfile "$PIDFILE" >"$LOG" 2>&1 </dev/null &
    for _ in $(seq 1 60); do
      if answers; then echo "dockerd started (pid $(cat "$PIDFILE"), data root $DATA_ROOT)"; exit 0; fi
      if ! kill -0 $! 2>/dev/null; then break; fi
      sleep 1
    done
    echo "dockerd did not start; the end of its log ($LOG):" >&2
    tail -n 20 "$LOG" >&2
    exit 1
    ;;
  stop)
    [ -f "$PIDFILE" ] || { echo "no daemon started by this script"; exit 0; }
    pid="$(cat "$PIDFILE")"
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 1 30); do kill -0 "$pid" 2>/dev/null || break; sleep 1; done
    if kill -0 "$pid" 2>/dev/null; then kill -KILL "$pid"; fi
    rm -f "$PIDFILE"
    echo "dockerd stopped"
    ;;
  status)
    if answers; then docker info --format 'daemon {{.ServerVersion}}, {{.Images}} images, {{.Containers}} containers'
    else echo "no daemon answers"; exit 1; fi
    ;;
  *)
    echo "usage: $0 start|stop|status" >&2; exit 2
    ;;
esac
