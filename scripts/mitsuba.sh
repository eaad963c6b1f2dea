#!/usr/bin/env bash
# Installs the peer renderer the benchmarks compare against: Mitsuba 3 (PyPI) and, for its
# vectorised `llvm_ad_rgb` variant, a libLLVM new enough for Dr.Jit (Debian 12's LLVM 15
# aborts in Dr.Jit's code generator; Debian's libllvm19 works). Idempotent. Prints the
# libLLVM path to export as DRJIT_LIBLLVM_PATH (empty when only `scalar_rgb` is available).
# Usage: export DRJIT_LIBLLVM_PATH=$(bash scripts/mitsuba.sh)
set -euo pipefail

if ! python3 -c 'import mitsuba, numpy' 2>/dev/null; then
  python3 -m pip install --quiet 'mitsuba==3.*' numpy >&2
fi
llvm=$(ls /usr/lib/x86_64-linux-gnu/libLLVM.so.19* 2>/dev/null | sort | tail -1 || true)
if [ -z "$llvm" ] && command -v apt-get >/dev/null; then
  sudo_=""
  [ "$(id -u)" = 0 ] || sudo_="sudo"
  { $sudo_ apt-get install -y -q libllvm19 >&2 \
    || { $sudo_ apt-get update -q >&2 && $sudo_ apt-get install -y -q libllvm19 >&2; }; } || true
  llvm=$(ls /usr/lib/x86_64-linux-gnu/libLLVM.so.19* 2>/dev/null | sort | tail -1 || true)
fi
echo "$llvm"
