#!/usr/bin/env bash
# Same numbers? Renders a fixed set of built-in scenes (1 and 2 ranks, both
# form-factor methods, every exchange, both projections, bake,
# a checkpoint after every shot) with two builds of `radiosity` and compares
# the outputs bit for bit: reports (less timings, paths and the device),
# EXR, PNG, the bake, and the checkpoint (its state's bits and its header
# less the seconds). For behaviour-preserving changes.
# Usage: scripts/compare-outputs.sh OLD_BINARY NEW_BINARY [WORK_DIR]
set -euo pipefail
old=$1 new=$2 dir=${3:-$(mktemp -d)}
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
run_set() {
  local bin=$1 out=$2 mpi="mpirun -n 2 --oversubscribe"
  mkdir -p "$out"
  run() {
    local name=$1; shift
    "$@" --out-dir "$out" --image "$out/$name.exr" --report "$out/$name.json" \
      --checkpoint "$out/$name.ckpt" --checkpoint-every 0.000001 --bake "$out/$name.glb" \
      >"$out/$name.log" 2>&1 || { echo "$name failed: see $out/$name.log" >&2; exit 1; }
  }
  run cornell1 "$bin" render cornell
  run cornell2 $mpi "$bin" render cornell
  run cornellH1 "$bin" render cornell --form-factor hemisphere
  run cornellH2 $mpi "$bin" render cornell --form-factor hemisphere --exchange sparse
  run cubes1 "$bin" render cubes-3
  run cubes2 $mpi "$bin" render cubes-3 --exchange form-factors --tile 4x4
  run cubesO2 $mpi "$bin" render cubes-3 --no-cache
  run b1 "$bin" render cubes-b1 --max-shots 20 --width 128
  run b1x2 $mpi "$bin" render cubes-b1 --max-shots 20 --width 128
  run tess1 "$bin" render cornell --projection tessellated --max-shots 400
  run tess2 $mpi "$bin" render cornell --projection tessellated --max-shots 400
  run class1 "$bin" render classroom-c1 --max-shots 60 --width 160
  run class2 $mpi "$bin" render classroom-c1 --max-shots 60 --width 160 --exchange sparse
  run nosplit1 "$bin" render cubes-2 --no-split --raster-pieces 0 --coarse-below 0 --shading flat --wireframe
}
run_set "$old" "$dir/old"
run_set "$new" "$dir/new"
python3 - "$dir/old" "$dir/new" <<'PY'
import hashlib, json, os, struct, sys
a_dir, b_dir = sys.argv[1], sys.argv[2]
VARIES = {"path", "timings", "device", "seconds", "transport_seconds", "per_rank", "load_balance", "load_balance_cpu", "measured_bytes_per_shot"}
def strip(v):
    if isinstance(v, dict):
        return {k: strip(x) for k, x in v.items() if k not in VARIES}
    if isinstance(v, list):
        return [strip(x) for x in v]
    return v
def counts(r):
    t = r["timings"]
    bytes_ = [(p["bytes_sent"], p["bytes_received"]) for p in r["parallel"]["per_rank"]]
    # Split shots and rectangles drawn depend on which rows were drawn
    # ahead (timing) on one process: only these counts are the same bits.
    return bytes_, [t[k] for k in ("cached_shots", "coarse_shots")]
def checkpoint(p):
    b = open(p, "rb").read()
    n = struct.unpack("<Q", b[8:16])[0]
    return strip(json.loads(b[16:16 + n])), hashlib.sha256(b[16 + n:]).hexdigest()
differ = 0
for name in sorted(f[:-5] for f in os.listdir(a_dir) if f.endswith(".json")):
    ra, rb = (json.load(open(f"{d}/{name}.json")) for d in (a_dir, b_dir))
    same = {"report": strip(ra) == strip(rb) and counts(ra) == counts(rb)}
    for ext in ("exr", "png", "glb"):
        same[ext] = open(f"{a_dir}/{name}.{ext}", "rb").read() == open(f"{b_dir}/{name}.{ext}", "rb").read()
    same["ckpt"] = checkpoint(f"{a_dir}/{name}.ckpt") == checkpoint(f"{b_dir}/{name}.ckpt")
    print(f"{name:10s} {ra['shots']:6d} shots  " + "  ".join(f"{k} {'same' if v else 'DIFFERS'}" for k, v in same.items()))
    differ += not all(same.values())
print("all identical" if differ == 0 else f"{differ} runs differ")
sys.exit(1 if differ else 0)
PY
