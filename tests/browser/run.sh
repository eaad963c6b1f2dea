#!/usr/bin/env bash
# Browser test of the viewer: builds `glimpse`, serves it on a free loopback port with a
# temporary data folder, and drives the page in headless Chromium (viewer.test.cjs) twice:
# without a token and with one. Exits non-zero on any failure. See README.md.
#
# Installs what it needs when missing: Debian's chromium (apt-get) and playwright-core
# (npm, into target/browser/node, not the source tree).
#
# Environment: GLIMPSE_BIN (use this binary instead of building), CHROMIUM (browser path,
# default /usr/bin/chromium), PLAYWRIGHT_CORE_VERSION (default 1.65).
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$(pwd)
OUT="$ROOT/target/browser"
mkdir -p "$OUT"

CHROMIUM=${CHROMIUM:-/usr/bin/chromium}
if [ ! -x "$CHROMIUM" ]; then
  echo "browser test: installing chromium (Debian package)"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null
fi
export CHROMIUM

NODE_PREFIX="$OUT/node"
if [ ! -f "$NODE_PREFIX/node_modules/playwright-core/package.json" ]; then
  echo "browser test: installing playwright-core (npm)"
  mkdir -p "$NODE_PREFIX"
  npm install --prefix "$NODE_PREFIX" --no-save --no-audit --no-fund --loglevel=error \
    "playwright-core@${PLAYWRIGHT_CORE_VERSION:-1.65}" >/dev/null
fi
export NODE_PATH="$NODE_PREFIX/node_modules"

BIN=${GLIMPSE_BIN:-}
if [ -z "$BIN" ]; then
  cargo build --quiet --bin glimpse
  BIN="$ROOT/target/debug/glimpse"
fi

SERVER_PID=""
DATA=""
cleanup() {
  if [ -n "$SERVER_PID" ]; then
    kill "$SERVER_PID" 2>/dev/null || true
    wait "$SERVER_PID" 2>/dev/null || true
  fi
  SERVER_PID=""
  [ -n "$DATA" ] && rm -rf "$DATA"
  DATA=""
}
trap cleanup EXIT

# Starts the server on 127.0.0.1:0 and reads the bound address from its log line
# ("listening on http://ADDR"), so there is no race for a port.
start_server() {
  DATA=$(mktemp -d -t glimpse-browser-XXXXXX)
  local log="$OUT/server$1.log"
  shift
  : >"$log" # truncate now: the background redirection below may happen after the first grep
  RUST_LOG=info "$BIN" serve --addr 127.0.0.1:0 --data "$DATA" --workers 1 "$@" >"$log" 2>&1 &
  SERVER_PID=$!
  BASE=""
  for _ in $(seq 1 100); do
    BASE=$(grep -o 'http://127\.0\.0\.1:[0-9]*' "$log" | head -n 1 || true)
    [ -n "$BASE" ] && break
    if ! kill -0 "$SERVER_PID" 2>/dev/null; then
      echo "browser test: the server exited:"; cat "$log"; exit 1
    fi
    sleep 0.1
  done
  if [ -z "$BASE" ]; then
    echo "browser test: the server did not start within 10 s:"; cat "$log"; exit 1
  fi
  echo "browser test: server at $BASE"
}

passed=0
failed=0
start_server ""
if node tests/browser/viewer.test.cjs "$BASE" "$OUT/viewer.png"; then
  passed=$((passed + 1))
else
  failed=$((failed + 1))
fi
cleanup

TOKEN="browser-test-token-$$"
start_server "-token" --token "$TOKEN"
if node tests/browser/viewer.test.cjs "$BASE" "$OUT/viewer-token.png" "$TOKEN"; then
  passed=$((passed + 1))
else
  failed=$((failed + 1))
fi
cleanup

# The plain closing line CI reads ("one word with a colon" may precede it).
echo "browser: $passed passed, $failed failed"
[ "$failed" -eq 0 ] || echo "(server logs in $OUT/server.log and $OUT/server-token.log)"
[ "$failed" -eq 0 ]
