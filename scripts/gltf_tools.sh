#!/usr/bin/env bash
# The glTF round trip's tools (tests/gltf_roundtrip.rs), installed when missing into the
# target folder, not the source tree:
#   - pygltflib (PyPI, pinned), the independent glTF writer scripts/gltf_export.py uses,
#     into target/pydeps (pip --target; put it on PYTHONPATH);
#   - the Khronos glTF validator (npm `gltf-validator`, pinned) into target/gltf-validator.
# usage: bash scripts/gltf_tools.sh ensure    (prints nothing on success)
#        bash scripts/gltf_tools.sh validate FILE.glb|FILE.gltf
#             (the validator's report as JSON on stdout; exit 1 on any error or warning)
set -euo pipefail
cd "$(dirname "$0")/.."
PYDEPS=target/pydeps
NODEDEPS=target/gltf-validator
PYGLTFLIB_VERSION=1.16.2
VALIDATOR_VERSION=2.0.0-dev.3.10

ensure() {
  if [ ! -f "$PYDEPS/pygltflib/__init__.py" ]; then
    echo "gltf tools: installing pygltflib $PYGLTFLIB_VERSION into $PYDEPS" >&2
    python3 -m pip install --quiet --disable-pip-version-check --no-warn-script-location --root-user-action=ignore \
      --target "$PYDEPS" "pygltflib==$PYGLTFLIB_VERSION" >&2
  fi
  if [ ! -f "$NODEDEPS/node_modules/gltf-validator/package.json" ]; then
    echo "gltf tools: installing gltf-validator $VALIDATOR_VERSION into $NODEDEPS" >&2
    mkdir -p "$NODEDEPS"
    npm install --prefix "$NODEDEPS" --no-save --no-audit --no-fund --loglevel=error \
      "gltf-validator@$VALIDATOR_VERSION" >&2
  fi
}

case "${1:-}" in
  ensure) ensure ;;
  validate)
    ensure
    NODE_PATH="$NODEDEPS/node_modules" node -e '
      const fs = require("fs");
      require("gltf-validator").validateBytes(new Uint8Array(fs.readFileSync(process.argv[1])))
        .then((r) => {
          console.log(JSON.stringify(r.issues));
          process.exit(r.issues.numErrors + r.issues.numWarnings === 0 ? 0 : 1);
        }, (e) => { console.error(String(e)); process.exit(2); });' "$2"
    ;;
  *) echo "usage: bash scripts/gltf_tools.sh ensure | validate FILE" >&2; exit 2 ;;
esac
