#!/usr/bin/env bash
# A throwaway PostgreSQL 15 for the tests (cluster.md "How it is tested").
#   bash scripts/pg.sh ensure   start it if it is not running; print its URL on stdout
#   bash scripts/pg.sh stop     stop it and remove its folder
# One server per checkout (its folder and port are kept in target/pg-state), shared by
# every test binary: each test creates its own database in it. The server runs as the
# `postgres` user when we are root (PostgreSQL refuses to run as root), listens on a free
# loopback port only, trusts local connections (nothing but this machine reaches it) and
# keeps its files in a temporary folder. The package is installed only where its binaries
# are missing. Nothing is started when GLIMPSE_TEST_DATABASE_URL names a server.
set -euo pipefail
cd "$(dirname "$0")/.."

PG_BIN=${GLIMPSE_PG_BIN:-/usr/lib/postgresql/15/bin}
STATE=target/pg-state
mkdir -p target
exec 9>target/pg.lock
flock 9

as_pg() {
  if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}

install_if_missing() {
  [ -x "$PG_BIN/initdb" ] && return 0
  echo "pg.sh: installing postgresql-15 (missing $PG_BIN/initdb)" >&2
  local sudo=""
  [ "$(id -u)" = 0 ] || sudo=sudo
  $sudo apt-get update -qq >&2
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq postgresql-15 >&2
}

free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'
}

running() {
  [ -f "$STATE" ] || return 1
  local dir port
  read -r dir port <"$STATE"
  [ -d "$dir" ] && as_pg "$PG_BIN/pg_ctl" -D "$dir/data" status >/dev/null 2>&1
}

# The server must not inherit the lock (fd 9) nor our stdout/stderr: a caller waiting for
# our output to end would wait for the server.
start_server() {
  as_pg "$PG_BIN/pg_ctl" -D "$1/data" -l "$1/server.log" -w -t 30 \
    -o "-c listen_addresses=127.0.0.1 -p $2 -c unix_socket_directories=$1 -c max_connections=300" \
    start 9>&- >>"$1/pg_ctl.log" 2>&1 </dev/null
}

url() {
  local dir port
  read -r dir port <"$STATE"
  echo "postgres://postgres@127.0.0.1:$port/postgres"
}

case "${1:-}" in
ensure)
  if ! running; then
    install_if_missing
    dir=$(mktemp -d /tmp/glimpse-pg.XXXXXX)
    chmod 755 "$dir"
    [ "$(id -u)" = 0 ] && chown postgres "$dir"
    port=$(free_port)
    as_pg "$PG_BIN/initdb" -D "$dir/data" -U postgres -A trust --no-sync >"$dir/initdb.log" 2>&1
    # fsync stays on: the cluster tests restart this server with `-m immediate` and
    # expect every committed job to be there afterwards.
    start_server "$dir" "$port"
    echo "$dir $port" >"$STATE"
  fi
  url
  ;;
stop)
  if [ -f "$STATE" ]; then
    read -r dir port <"$STATE"
    as_pg "$PG_BIN/pg_ctl" -D "$dir/data" -m fast -w stop 9>&- >&2 || true
    rm -rf "$dir" "$STATE"
  fi
  ;;
restart-immediate)
  # The crash test: stop without a shutdown checkpoint (like a power cut for the
  # clients), then start again on the same port.
  read -r dir port <"$STATE"
  as_pg "$PG_BIN/pg_ctl" -D "$dir/data" -m immediate -w stop 9>&- >&2
  start_server "$dir" "$port"
  ;;
*)
  echo "usage: bash scripts/pg.sh ensure|stop|restart-immediate" >&2
  exit 2
  ;;
esac
