#!/usr/bin/env bash
# The whole test suite, on a fresh machine: installs what the tests need, then runs
#   1. every Rust test (unit tests beside the code, integration tests in tests/ that start
#      the real server on loopback and talk HTTP + WebSocket to it),
#   2. the browser test of the viewer in headless Chromium (tests/browser/run.sh).
# Usage: bash scripts/test.sh        (CI: .ci/run calls exactly this)
set -euo pipefail
cd "$(dirname "$0")/.."

# The Rust toolchain is the machine's own (rustup). SQLite is compiled in (sqlx's bundled
# libsqlite3), FLIP's C++ is built by its crate, Intel Open Image Denoise comes from
# scripts/oidn.sh (PyPI). PostgreSQL: the server named by GLIMPSE_TEST_DATABASE_URL, or
# else a throwaway PostgreSQL 15 started here (scripts/pg.sh installs the package only if
# it is missing) and stopped when the tests end.
if [ -z "${GLIMPSE_TEST_DATABASE_URL:-}" ]; then
  trap 'bash scripts/pg.sh stop' EXIT
  GLIMPSE_TEST_DATABASE_URL=$(bash scripts/pg.sh ensure)
  export GLIMPSE_TEST_DATABASE_URL
fi
# Intel Open Image Denoise for src/denoise's tests (loaded at run time; from PyPI).
bash scripts/oidn.sh >/dev/null
cargo test --no-fail-fast
# The service contract, durability and storage-fault tests once more, on PostgreSQL (cluster.md).
GLIMPSE_TEST_BACKEND=postgres cargo test --no-fail-fast --test service_api --test service_durability --test service_faults

if [ -f tests/browser/run.sh ] && [ "${GLIMPSE_SKIP_BROWSER:-0}" != 1 ]; then
  bash tests/browser/run.sh
fi
