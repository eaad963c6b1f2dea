#!/usr/bin/env bash
# API conformance run: schemathesis (PyPI) generates requests from api/openapi.yaml against
# a live `glimpse serve` on a loopback port with a temporary --data folder, and checks that
#   - no response is a server error (not_a_server_error: no 5xx other than the documented
#     503), and
#   - every response body matches the schema documented for its status
#     (response_schema_conformance).
# Bounded: --max-examples per operation and a --max-time budget. The WebSocket operation is
# left out (schemathesis speaks HTTP only; tests/openapi_contract.rs covers its handshake).
#
# Usage: bash scripts/conformance.sh
# Environment: GLIMPSE_BIN (binary to test; default: build the dev binary),
#   MAX_EXAMPLES (default 20), MAX_TIME (seconds, default 180), SEED (default 1),
#   CHECKS (default not_a_server_error,response_schema_conformance).
# Reports (JUnit XML) go to target/conformance/. Exit status: schemathesis's (0 = clean).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
OUT="$ROOT/target/conformance"
mkdir -p "$OUT"

if ! command -v schemathesis >/dev/null 2>&1; then
  echo "conformance: installing schemathesis (PyPI)"
  python3 -m pip install --quiet --disable-pip-version-check schemathesis
fi

BIN=${GLIMPSE_BIN:-}
if [ -z "$BIN" ]; then
  cargo build --quiet --bin glimpse
  BIN="$ROOT/target/debug/glimpse"
fi

DATA=$(mktemp -d -t glimpse-conformance-XXXXXX)
LOG="$OUT/server.log"
SERVER_PID=""
REAPER_PID=""
cleanup() {
  [ -n "$REAPER_PID" ] && kill "$REAPER_PID" 2>/dev/null || true
  if [ -n "$SERVER_PID" ] && kill -0 "$SERVER_PID" 2>/dev/null; then
    kill -INT "$SERVER_PID" 2>/dev/null || true # graceful: Ctrl-C
    for _ in $(seq 1 50); do kill -0 "$SERVER_PID" 2>/dev/null || break; sleep 0.2; done
    kill -KILL "$SERVER_PID" 2>/dev/null || true
  fi
  rm -rf "$DATA"
}
trap cleanup EXIT

# Generated scenes are valid documents of any size the schema allows: keep each render
# cheap (small images, short queue) so the run measures the API, not the renderer.
: >"$LOG" # truncate now: the background redirection may happen after the first grep
"$BIN" serve --addr 127.0.0.1:0 --data "$DATA" --workers 1 --queue 8 --max-pixels 4096 >"$LOG" 2>&1 &
SERVER_PID=$!
BASE=""
for _ in $(seq 1 100); do
  BASE=$(grep -o 'http://127\.0\.0\.1:[0-9]*' "$LOG" | head -n 1 || true)
  [ -n "$BASE" ] && break
  kill -0 "$SERVER_PID" 2>/dev/null || { echo "conformance: the server exited:"; cat "$LOG"; exit 1; }
  sleep 0.1
done
[ -n "$BASE" ] || { echo "conformance: the server did not start"; cat "$LOG"; exit 1; }
echo "conformance: server at $BASE (data $DATA)"

# Reaper: a generated scene may still ask for many samples per pixel; cancel any job that
# has run for more than 5 s so the worker stays free for the requests under test.
python3 - "$BASE" <<'EOF' &
import json, sys, time, urllib.request
base = sys.argv[1]
while True:
    try:
        with urllib.request.urlopen(base + "/v1/jobs?state=running&limit=500", timeout=5) as r:
            for job in json.load(r).get("jobs", []):
                if ((job.get("progress") or {}).get("elapsed_ms") or 0) > 5000:
                    req = urllib.request.Request(base + "/v1/jobs/" + job["id"] + "/cancel", method="POST")
                    try:
                        urllib.request.urlopen(req, timeout=5).close()
                    except Exception:
                        pass
    except Exception:
        pass
    time.sleep(1)
EOF
REAPER_PID=$!

CHECKS=${CHECKS:-not_a_server_error,response_schema_conformance}
set +e
# From target/conformance: schemathesis keeps its cache (.schemathesis/) in the current
# folder, which must not be the source tree.
cd "$OUT"
schemathesis run "$ROOT/api/openapi.yaml" \
  --url "$BASE" \
  --checks "$CHECKS" \
  --max-examples "${MAX_EXAMPLES:-20}" \
  --max-time "${MAX_TIME:-180}" \
  --seed "${SEED:-1}" \
  --workers 1 \
  --request-timeout 20 \
  --exclude-path '/v1/jobs/{id}/stream' \
  --generation-database none \
  --suppress-health-check all \
  --report junit --report-junit-path "$OUT/junit.xml" \
  --no-color 2>&1 | tee "$OUT/schemathesis.log"
status=${PIPESTATUS[0]}
set -e
cd "$ROOT"

alive="yes"
kill -0 "$SERVER_PID" 2>/dev/null || alive="no (crashed: see $LOG)"
panics=$(grep -c -i "panicked" "$LOG" || true)
echo
echo "conformance summary"
echo "  checks:           $CHECKS"
echo "  schemathesis:     exit $status ($([ "$status" -eq 0 ] && echo clean || echo FAILURES))"
echo "  server alive:     $alive"
echo "  panics in log:    $panics"
echo "  reports:          $OUT/schemathesis.log, $OUT/junit.xml, $LOG"
[ "$alive" = "yes" ] || status=1
[ "$panics" -eq 0 ] || status=1
exit "$status"
