#!/usr/bin/env bash
# Image error against wall time in one sitting: this renderer (the solve
# stopped at unshot 1e-2 and 1e-3, the image gathered or interpolated) and
# Mitsuba 3 with next-event estimation (several samples a pixel), each
# scored by `radiosity compare` (SMAPE on 4x4 blocks) against the cached
# reference image REF.exr (whose .json gives the size). Appends rows
# `scene,renderer,setting,seconds,smape_percent` to OUT.csv; chart them with
# `radiosity-lab image-time OUT.csv`.
# Usage: scripts/image-time.sh SCENE REF.exr OUT.csv [render flags...]
# Needs a release build and Mitsuba 3 (see scripts/make-references.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
scene=$1; ref=$2; out=$3; shift 3
bin=target/release/radiosity
export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
read -r w h < <(python3 -c "import json,sys;d=json.load(open(sys.argv[1]));print(*d['size'])" "${ref%.exr}.json")
name=$(basename "$scene" .gltf)
mkdir -p "$(dirname "$out")"
[ -s "$out" ] || echo "scene,renderer,setting,seconds,smape_percent" > "$out"
score() { "$bin" compare "$1" "$ref" | awk '{print $2}'; }
for th in 1e-2 1e-3; do for g in 0 256; do
  t0=$(date +%s.%N)
  "$bin" render "$scene" --width "$w" --height "$h" --threshold "$th" --gather "$g" "$@" \
    --image "$tmp/r.exr" --report "$tmp/r.json" >/dev/null 2>&1
  t1=$(date +%s.%N)
  echo "$name,radiosity,unshot $th gather $g,$(echo "$t1-$t0" | bc),$(score "$tmp/r.exr")" | tee -a "$out"
done; done
"$bin" scene "$scene" --nodes "$tmp/nodes.json" "$@" >/dev/null 2>&1
for spp in ${SPPS:-64 256 1024 4096}; do
  t0=$(date +%s.%N)
  python3 scripts/reference.py "$tmp/nodes.json" --image "$tmp/m.exr" --width "$w" --height "$h" \
    --spp "$spp" --passes 1 >/dev/null 2>&1
  t1=$(date +%s.%N)
  echo "$name,mitsuba,$spp spp,$(echo "$t1-$t0" | bc),$(score "$tmp/m.exr")" | tee -a "$out"
done
