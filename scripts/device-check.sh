#!/usr/bin/env bash
# The device check, for a machine with a GPU (about ten minutes): the
# adapter and driver, a cold build, the suite's device tests, the device's
# drawing against the CPU's node by node, the bench with each projection and
# rasteriser at 128x512 and 512x2048, and mpirun on 4 and 8 ranks. Writes
# one summary table to OUT/summary.md (default out/device-check) and prints
# it; each step's log lies beside it. A step that fails is a row that says
# so; the script goes on and exits non-zero at the end.
# Usage: scripts/device-check.sh   (SCENE=cubes-b1 SHOTS=200 to change the bench;
#   QUICK=1 keeps the build and leaves the suite out, to try the script)
set -uo pipefail
cd "$(dirname "$0")/.."
out="${OUT:-out/device-check}"
scene="${SCENE:-cubes-b1}"
shots="${SHOTS:-200}"
mkdir -p "$out"
summary="$out/summary.md"
bin=target/release/radiosity
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
failed=0
{
  echo "# Device check, $(date -u +%Y-%m-%dT%H:%MZ), $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
  echo
  echo "| check | result | detail |"
  echo "|---|---|---|"
} >"$summary"
row() { echo "| $1 | $2 | $3 |" >>"$summary"; }
step() { # NAME LOG COMMAND...: a row with its seconds, pass or FAIL
  local name=$1 log=$2 t0 t1
  shift 2
  t0=$(date +%s.%N)
  if "$@" >"$out/$log" 2>&1; then
    t1=$(date +%s.%N)
    row "$name" pass "$(printf '%.1f s' "$(echo "$t1 - $t0" | bc)") ($log)"
  else
    failed=1
    row "$name" FAIL "see $out/$log"
  fi
}
# A report's number: field FIELD (a dotted path) of JSON file FILE.
field() { python3 -c "import json,sys; d=json.load(open(sys.argv[1]))
for k in sys.argv[2].split('.'): d=d[k]
print(d)" "$1" "$2"; }

# 1. The adapter and the driver.
gpu=$(nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>/dev/null | head -1)
row "GPU (nvidia-smi)" "${gpu:-none}" ""
vk=$(vulkaninfo --summary 2>/dev/null | grep -E "deviceName|driverName" | sed 's/^ *//' | paste -sd ';' -)
row "Vulkan devices" "${vk:-vulkaninfo missing}" ""

# 2. A cold build (installs what is missing first).
if [ -z "${QUICK:-}" ]; then
  source scripts/setup.sh >"$out/setup.log" 2>&1 || row setup FAIL "see $out/setup.log"
  set +e
  step "cold build" build.log bash -c "cargo clean --release -p radiosity && cargo build --release --locked --workspace --all-targets"
fi

# 3. The suite's device tests: rasterisers, traps, projections, lattice
# grids, rank invariance (auto is the device where there is a GPU).
for t in rasterisers traps projections reference::lattices mpi determinism; do
  [ -n "${QUICK:-}" ] && break
  step "suite: $t" "suite-${t//:/_}.log" cargo test --release --locked --test suite -- "$t"
done

# 4. The device's drawing against the CPU's, node by node; the adapter and
# rasteriser the report names.
for r in device cpu; do
  "$bin" render "$scene" --width 0 --max-shots "$shots" --rasteriser "$r" \
    --report "$out/$r.json" >"$out/$r.log" 2>&1 || { failed=1; row "render $r" FAIL "see $out/$r.log"; }
done
if [ -f "$out/device.json" ] && [ -f "$out/cpu.json" ]; then
  worst=$(python3 - "$out/device.json" "$out/cpu.json" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:])
B = {s['node']: sum(s['radiosity']) for s in b['surfaces']}
print(max(abs(sum(s['radiosity']) / B[s['node']] - 1) if B[s['node']] else 0 for s in a['surfaces']))
PY
)
  row "device vs CPU, worst node" "$worst" "$(field "$out/device.json" device) / $(field "$out/device.json" settings.rasteriser)"
fi

# 5. The bench: each projection and rasteriser at two resolutions.
for res in 128x512 512x2048; do
  for proj in exact tessellated; do
    for r in device cpu; do
      j="$out/bench-$res-$proj-$r.json"
      if "$bin" render "$scene" --width 0 --max-shots "$shots" --resolution "$res" \
        --projection "$proj" --rasteriser "$r" --report "$j" >"$out/bench.log" 2>&1; then
        row "bench $scene $res $proj $r" "$(field "$j" timings.median_shot_ms) ms a shot" \
          "solve $(field "$j" timings.solve) s"
      else
        failed=1
        row "bench $res $proj $r" FAIL "see $out/bench.log"
      fi
    done
  done
done

# 6. Ranks: the same bits on 1, 4 and 8 ranks, and their times.
for n in 1 4 8; do
  j="$out/ranks-$n.json"
  cmd=("$bin" render "$scene" --width 0 --max-shots "$shots" --report "$j")
  [ "$n" -gt 1 ] && cmd=(mpirun -n "$n" --oversubscribe "${cmd[@]}")
  if "${cmd[@]}" >"$out/ranks-$n.log" 2>&1; then
    same=$(python3 -c "import json,sys; a,b=(json.load(open(p))['surfaces'] for p in sys.argv[1:]); print('same bits' if a==b else 'DIFFERENT')" "$out/ranks-1.json" "$j")
    row "mpirun -n $n" "$same" "solve $(field "$j" timings.solve) s"
  else
    failed=1
    row "mpirun -n $n" FAIL "see $out/ranks-$n.log"
  fi
done

cat "$summary"
exit "$failed"
