#!/usr/bin/env bash
# The whole test suite, on a fresh machine: installs what the tests need, then runs
#   1. every Rust test (unit tests beside the code, integration tests in tests/ that start
#      the real server on loopback and talk HTTP + WebSocket to it),
#   2. the browser test of the viewer in headless Chromium (tests/browser/run.sh).
# Usage: bash scripts/test.sh        (CI: .ci/run calls exactly this)
set -euo pipefail
cd "$(dirname "$0")/.."

# The Rust toolchain is the machine's own (rustup); nothing else is needed for cargo test:
# SQLite is compiled in (sqlx's bundled libsqlite3), FLIP's C++ is built by its crate.
cargo test --no-fail-fast

if [ -f tests/browser/run.sh ] && [ "${GLIMPSE_SKIP_BROWSER:-0}" != 1 ]; then
  bash tests/browser/run.sh
fi
