#!/usr/bin/env bash
# Installs Intel Open Image Denoise 2.5.1 (CPU device only) into target/oidn/lib, where
# src/denoise finds it at run time. The library comes from PyPI's `pyoidn` wheel, which
# ships Intel's prebuilt shared objects; we keep only the CPU parts (the CUDA, HIP and
# SYCL devices add ~40 MB and are never loaded here).
# Idempotent: exits at once when the library is already there. Prints the folder.
# Usage: bash scripts/oidn.sh
set -euo pipefail
cd "$(dirname "$0")/.."

version=2.5.1
dest=target/oidn/lib
if [ -f "$dest/libOpenImageDenoise.so.2" ] \
  && [ -f "$dest/libOpenImageDenoise_core.so.$version" ] \
  && [ -f "$dest/libOpenImageDenoise_device_cpu.so.$version" ] \
  && [ -f "$dest/libtbb.so.12" ]; then
  echo "$PWD/$dest"
  exit 0
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 -m pip download --quiet --no-deps --only-binary=:all: \
  "pyoidn==$version.0" -d "$tmp" >&2
wheel=$(ls "$tmp"/pyoidn-"$version".0-*.whl)

# A wheel is a zip: unzip(1) if present, else Python's zipfile (always there with pip).
# The wheel's .so symlinks are stored as full copies; we take only the names the loader
# asks for (each file's SONAME or NEEDED entry), see readelf -d.
mkdir -p "$tmp/x" "$dest"
python3 - "$wheel" "$tmp/x" <<'PY'
import sys, zipfile
wanted = ("libOpenImageDenoise.so.2", "libOpenImageDenoise_core.so.2.5.1",
          "libOpenImageDenoise_device_cpu.so.2.5.1", "libtbb.so.12")
with zipfile.ZipFile(sys.argv[1]) as z:
    for name in wanted:
        z.extract("pyoidn/oidn/lib/" + name, sys.argv[2])
PY
# Copy to a temporary name first, then rename, dependencies first and the entry library
# last: a build or test racing this script never sees a half-installed library.
for f in libtbb.so.12 "libOpenImageDenoise_core.so.$version" \
  "libOpenImageDenoise_device_cpu.so.$version" libOpenImageDenoise.so.2; do
  cp "$tmp/x/pyoidn/oidn/lib/$f" "$dest/.$f.part"
  mv "$dest/.$f.part" "$dest/$f"
done
echo "$PWD/$dest"
