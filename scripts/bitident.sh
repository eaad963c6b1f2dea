#!/usr/bin/env bash
# Are two builds' pictures the same bit for bit? Renders every bundled scene in every mode
# (small: 96×72, 8 spp, seed 3) with both binaries and compares the EXR bytes; exits 1 on
# any difference. For refactorings that must not change a pixel.
# Usage: bash scripts/bitident.sh BASE_BINARY NEW_BINARY
set -u
BASE=$1; NEW=$2
cd "$(dirname "$0")/.."
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
fail=0
for s in scenes/*.json; do
  n=$(basename "$s" .json)
  for m in reference progressive guo; do
    for b in base new; do
      bin=$BASE; [ $b = new ] && bin=$NEW
      "$bin" render "$s" --output "$OUT/$n-$m-$b.exr" --mode $m --size 96x72 --spp 8 --seed 3 \
        >/dev/null 2>&1 || { echo "render failed: $b $n $m"; fail=1; }
    done
    if cmp -s "$OUT/$n-$m-base.exr" "$OUT/$n-$m-new.exr"; then echo "same  $n $m"; else echo "DIFF  $n $m"; fail=1; fi
  done
done
exit $fail
