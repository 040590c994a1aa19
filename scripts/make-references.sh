#!/usr/bin/env bash
# Makes the cached path-traced references of scenes (docs/references/SCENE.json),
# each with the command that made it: per node to --target relative standard
# error (scripts/reference.py, next-event estimation). Needs Mitsuba 3
# (pip install mitsuba numpy; apt-get install libllvm19) and a release build.
# Usage: scripts/make-references.sh SCENE...   (e.g. family-boxes-2)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/radiosity
target="${TARGET:-1e-3}"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for scene in "$@"; do
  "$bin" scene "$scene" --nodes "$tmp/nodes.json" >/dev/null
  cmd="radiosity scene $scene --nodes nodes.json && DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so python3 scripts/reference.py nodes.json --target $target --max-seconds 300"
  DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}" python3 scripts/reference.py "$tmp/nodes.json" --target "$target" --max-seconds 300 > "$tmp/ref.json"
  python3 - "$scene" "$cmd" "$tmp/ref.json" "docs/references/$scene.json" <<'PY'
import json, os, sys
scene, cmd, src, dst = sys.argv[1:]
r = json.load(open(src))
out = {"scene": scene, "command": cmd, **r}
tmp = dst + ".tmp"
with open(tmp, "w") as f:
    json.dump(out, f, indent=1)
os.replace(tmp, dst)
print(f"{scene}: {r['seconds']:.1f} s, converged {r['converged']}", file=sys.stderr)
PY
done
