#!/usr/bin/env bash
# The viewer's solve against the renderer's on the same scene: solve seconds
# to the stop rule, each run RUNS times (medians), the viewer under Xvfb with
# its window painting as usual (its UI and view thread share the cores).
# Usage: scripts/bench-viewer.sh [SCENE] [RUNS] [extra flags for both]
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
scene=${1:-cornell}; runs=${2:-3}; shift $(( $# < 2 ? $# : 2 )) || true
cargo build --release --locked --workspace >/dev/null
dir=$(mktemp -d)
for i in $(seq "$runs"); do
  target/release/radiosity render "$scene" --width 0 --report "$dir/r$i.json" --checkpoint "$dir/c$i.ckpt" "$@" 2>/dev/null
  xvfb-run -a target/release/radiosity-viewer "$scene" --frame-stats "$dir/v$i.json" \
    --exit-when-converged --exit-after 600 "$@" 2>/dev/null
done
python3 - "$dir" "$runs" <<'PY'
import json, statistics, sys
d, n = sys.argv[1], int(sys.argv[2])
r = [json.load(open(f"{d}/r{i}.json")) for i in range(1, n + 1)]
v = [json.load(open(f"{d}/v{i}.json")) for i in range(1, n + 1)]
rs = [x["timings"]["solve"] for x in r]
vs = [x["solve_seconds"] for x in v]
assert all(x["converged"] for x in v), "a viewer run did not converge"
print(f"renderer solve (refinement passes included): {[round(x, 2) for x in rs]} s, shots {r[0]['shots']}")
print(f"viewer solve (final solve only):             {[round(x, 2) for x in vs]} s, shots {v[0]['shots']}, frames {[x['frames'] for x in v]}")
print(f"ratio of medians: {statistics.median(vs) / statistics.median(rs):.2f}")
PY
