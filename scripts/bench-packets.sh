#!/usr/bin/env bash
# A shot against its ray-packet peer, in the same run on the same cores
# (issue 19's goal: the 4096-cube room's shot within 3x of Embree 3's 8-ray
# packets casting one ray per cell). Logs the hemispheres of a bench solve,
# casts the same hemispheres' rays with Embree (scripts/packets.c, nearest
# hit into an item buffer, rows shared by the threads), then times the
# renderer's default shot and `--ranks 2 --batch 64`, alternating, and
# prints the ratios.
#
#   SCENES="cubes-4 cubes-16" SHOTS=640 ROUNDS=2 scripts/bench-packets.sh
#
# Installs libembree-dev (Debian 12: Embree 3.13) and gcc when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
install_missing libembree-dev gcc libc6-dev
cargo build --release --locked --bin radiosity --bin radiosity-lab
bin=target/release/radiosity
lab=target/release/radiosity-lab
SCENES=${SCENES:-"cubes-4 cubes-16"}
SHOTS=${SHOTS:-640}
ROUNDS=${ROUNDS:-2}
THREADS=${THREADS:-$(nproc)}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
gcc -O3 -march=native -fopenmp scripts/packets.c -lembree3 -lm -o "$work/packets"
# The bench's shot settings (docs/notebook/shot-phases.md).
settings=(--no-cache --coarse-below 0 --shots "$SHOTS" --converge 0)
mean_ms() { # bench args...: the table's mean shot ms
  "$lab" bench "$@" 2>/dev/null | awk -F'|' '/^\| [a-z]/ && $2 !~ /scene/ {gsub(/ /, "", $8); print $8}'
}
for scene in $SCENES; do
  "$bin" scene "$scene" --nodes "$work/nodes.json" >/dev/null
  # One shot at a time, nothing drawn ahead: each logged whole hemisphere
  # is a shot's (the refinement pass's first, then the bench's).
  RUST_LOG=radiosity::hemispheres=trace "$lab" bench --scenes "$scene" "${settings[@]}" \
    --no-look-ahead 2>"$work/log" >/dev/null
  python3 - "$work/nodes.json" "$work/log" "$SHOTS" "$work/input.bin" <<'EOF'
import json, re, struct, sys
nodes, log, shots, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
tris = [c for n in json.load(open(nodes))["nodes"] for t in n["triangles"] for c in t]
num = r"\[([^\]]*)\]"
frames = []
for line in open(log):
    if "radiosity::hemispheres" in line:
        vecs = re.findall(num, line.split("hemisphere ", 1)[1])
        frames.append([float(x) for v in vecs for x in v.split(",")])
frames = frames[-shots:]
flat = [x for p in tris for x in p]
lo = [min(flat[i::3]) for i in range(3)]
hi = [max(flat[i::3]) for i in range(3)]
extent = max(h - l for l, h in zip(lo, hi))
with open(out, "wb") as f:
    f.write(struct.pack("<4If", len(tris) // 3, len(frames), 128, 512, extent))
    f.write(struct.pack(f"<{len(flat)}f", *flat))
    f.write(struct.pack(f"<{12 * len(frames)}f", *[x for fr in frames for x in fr]))
EOF
  for r in $(seq "$ROUNDS"); do
    packets=$(OMP_NUM_THREADS=$THREADS "$work/packets" "$work/input.bin")
    one=$(mean_ms --scenes "$scene" "${settings[@]}")
    two=$(mean_ms --scenes "$scene" "${settings[@]}" --ranks 2 --batch 64)
    p=$(echo "$packets" | sed -E 's/.*mean ([0-9.]+) ms.*/\1/')
    echo "$scene round $r: packets: $packets"
    awk -v s="$scene" -v p="$p" -v a="$one" -v b="$two" 'BEGIN {
      printf "%s: mean shot %.2f ms (%.1fx the packets), --ranks 2 --batch 64 %.2f ms (%.1fx); packets %.2f ms\n", s, a, a / p, b, b / p, p }'
  done
done
