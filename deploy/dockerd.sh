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
#
# Debian's docker.io enables its own docker.service and docker.socket: on a host where systemd runs, that daemon
# starts at boot (or at the first `docker` command, through the socket) with iptables on. `start` does not reuse
# a daemon it did not start unless that daemon runs with --iptables=false; otherwise it stops and says how to
# disable Debian's (systemctl disable --now docker.service docker.socket). ROBOBPP_REUSE_DOCKERD=1 uses whatever
# daemon answers, as it is.
set -euo pipefail

DATA_ROOT="${DOCKER_DATA_ROOT:-/var/lib/docker}"
RUN_DIR="${DOCKER_RUN_DIR:-/run/robobpp-dockerd}"
PIDFILE="$RUN_DIR/dockerd.pid"
LOG="$RUN_DIR/dockerd.log"

answers() { docker info >/dev/null 2>&1; }

# The daemon that answers, when this script did not start it: say whether it leaves the firewall alone.
foreign_daemon() {
  local pid args
  pid="$(pgrep -o -x dockerd || true)"
  if [ -z "$pid" ]; then
    echo "a Docker daemon answers but no dockerd process is visible here (another host or container?)" >&2
    return 1
  fi
  args="$(tr '\0' ' ' <"/proc/$pid/cmdline")"
  case " $args " in
    *" --iptables=false "*) echo "a Docker daemon started with --iptables=false answers (pid $pid); using it"; return 0 ;;
  esac
  {
    echo "a Docker daemon this script did not start answers (pid $pid: $args)."
    echo "It manages the firewall (no --iptables=false): on Debian it is docker.io's own docker.service."
    echo "Stop it and keep it from starting again (the socket starts it at the first docker command):"
    echo "  systemctl disable --now docker.service docker.socket"
    echo "then run '$0 start' again; or set ROBOBPP_REUSE_DOCKERD=1 to use that daemon as it is."
  } >&2
  return 1
}

# The network-namespace mounts (nsfs) dockerd leaves under its exec root when it is stopped; a later daemon or
# `umount -a` trips over them. Only those of the default exec root, which the daemon of this script uses.
unmount_netns() {
  local mnt
  for mnt in $(awk '$3 == "nsfs" && $2 ~ "^/(var/)?run/docker/netns/" {print $2}' /proc/mounts); do
    umount "$mnt" 2>/dev/null || umount -l "$mnt" 2>/dev/null || echo "could not unmount $mnt" >&2
  done
}

case "${1:-}" in
  start)
    if answers; then
      if [ -f "$PIDFILE" ] && kill -0 "$(cat "$PIDFILE")" 2>/dev/null; then echo "dockerd of this script already runs"; exit 0; fi
      if [ "${ROBOBPP_REUSE_DOCKERD:-}" = 1 ]; then echo "a Docker daemon already answers; using it (ROBOBPP_REUSE_DOCKERD=1)"; exit 0; fi
      foreign_daemon && exit 0
      exit 1
    fi
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
    unmount_netns
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
