#!/usr/bin/env bash
# Two ranks against one, two builds side by side: the README's "2 ranks on
# one core each" medians. Each round runs build A on 1 rank (pinned to core
# 0), A on 2 ranks (one core each), then B the same, so both builds see the
# same hour; prints each round's whole-solve times and ratios, then the
# medians. 100 shots in batches of 64, as in docs/notebook/ranks.md "Ranks".
#
#   scripts/pairs-mpi.sh OLD_BINARY NEW_BINARY [SCENE [ROUNDS]] [-- FLAGS...]
#   scripts/pairs-mpi.sh /tmp/before target/release/radiosity cubes-b1 20
#
# The same binary twice measures the sitting's own spread.
set -euo pipefail
A=$1 B=$2
scene=${3:-cubes-b1}
rounds=${4:-20}
shift $(($# < 4 ? $# : 4))
[ "${1:-}" = "--" ] && shift
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 LP_NUM_THREADS=1
export OMPI_MCA_btl=${OMPI_MCA_btl:-self,vader,tcp}
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/runtime-$(id -u)}
mkdir -p -m 700 "$XDG_RUNTIME_DIR"
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
args=(render "$scene" --resolution 128x512 --exchange hemispheres --batch 64
  --max-shots 100 --threshold 0 --width 0 --refine-shading 0 --deal-bounds on "$@")
solve() { python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['timings']['solve'])" "$1"; }
for i in $(seq 1 "$rounds"); do
  line=""
  for X in A B; do
    bin=${!X}
    taskset -c 0 "$bin" "${args[@]}" --out-dir "$out" --report "$out/1$X.json" >/dev/null 2>&1
    mpirun --bind-to core -n 2 -x LP_NUM_THREADS "$bin" "${args[@]}" --out-dir "$out" \
      --report "$out/2$X.json" >/dev/null 2>&1
    one=$(solve "$out/1$X.json") two=$(solve "$out/2$X.json")
    line+="$X $one $two "
  done
  echo "$line" | tee -a "$out/rounds"
done
python3 - "$out/rounds" <<'PY'
import sys, statistics as st
rows = [l.split() for l in open(sys.argv[1]) if l.strip()]
for k, name in ((0, "A"), (3, "B")):
    one = [float(r[k + 1]) for r in rows]
    two = [float(r[k + 2]) for r in rows]
    ratio = [a / b for a, b in zip(one, two)]
    print(f"{name}: median solve 1 rank {st.median(one):.3f} s, 2 ranks {st.median(two):.3f} s, "
          f"ratio median {st.median(ratio):.3f}x ({min(ratio):.3f}-{max(ratio):.3f}, {len(rows)} rounds)")
PY
