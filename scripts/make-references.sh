#!/usr/bin/env bash
# Makes the cached path-traced references of scenes, each with the command
# that made it (scripts/reference.py, next-event estimation):
#   per node to TARGET relative standard error -> docs/references/SCENE.json
#   with IMAGE=1, the camera image (128 px wide, SPP samples a pixel in 8
#   passes) -> docs/references/images/SCENE.{exr,json}
# Needs Mitsuba 3 (pip install mitsuba numpy; apt-get install libllvm19) and
# a release build of the renderer.
# Usage: [IMAGE=1] scripts/make-references.sh SCENE...   (e.g. family-boxes-2)
#   LIGHTS="--sun X,Y,Z,E --sky L": lights for the scene (as render takes them)
#   NAME=N: the reference's name (default: the scene's; one scene then)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/radiosity
target="${TARGET:-1e-3}"
spp="${SPP:-8192}"
export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}"
llvm="DRJIT_LIBLLVM_PATH=$DRJIT_LIBLLVM_PATH"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
lights="${LIGHTS:-}"
for scene in "$@"; do
  name="${NAME:-$scene}"
  "$bin" scene "$scene" --nodes "$tmp/nodes.json" $lights >/dev/null
  if [ -n "${IMAGE:-}" ]; then
    out="docs/references/images/$name.exr"
    args="--image $out --width 128 --spp $spp --passes 8"
    python3 scripts/reference.py "$tmp/nodes.json" $args
    meta="${out%.exr}.json"
    src="$meta"
  else
    args="--target $target --max-seconds 300"
    python3 scripts/reference.py "$tmp/nodes.json" $args > "$tmp/ref.json"
    meta="docs/references/$name.json"
    src="$tmp/ref.json"
  fi
  cmd="radiosity scene $scene --nodes nodes.json${lights:+ $lights} && $llvm python3 scripts/reference.py nodes.json $args"
  python3 - "$name" "$cmd" "$src" "$meta" <<'PY'
import json, os, sys
scene, cmd, src, dst = sys.argv[1:]
r = json.load(open(src))
r.pop("command", None)
out = {"scene": scene, "command": cmd, **r}
tmp = dst + ".tmp"
with open(tmp, "w") as f:
    json.dump(out, f, indent=1)
os.replace(tmp, dst)
print(f"{scene}: {r['seconds']:.1f} s", file=sys.stderr)
PY
done
