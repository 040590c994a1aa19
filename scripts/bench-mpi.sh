#!/usr/bin/env bash
# The paper's comparison (its figures 8-12) on this machine: time per shot,
# bytes per shot and load balance against the rank count for the three
# exchanges, plus load balance against hemisphere resolution and tile size.
# Writes docs/bench/runs/*.json, docs/bench/results.csv and the charts.
#
#   SHOTS=20 RANKS="1 2 4 8 16" SCENES="cubes-b1 classroom-c1 classroom-c3" scripts/bench-mpi.sh
#
# Ranks beyond the cores are oversubscribed (each rank's lavapipe gets one
# thread then), so times above 2 ranks on a 2-core machine show overheads,
# not speedup.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo build --release --locked --bin radiosity --bin radiosity-lab
bin=target/release/radiosity
SHOTS=${SHOTS:-20}
RANKS=${RANKS:-"1 2 4 8 16"}
SCENES=${SCENES:-"cubes-b1 classroom-c1 classroom-c3"}
SWEEP_SCENE=${SWEEP_SCENE:-classroom-c1}
SWEEP_RANKS=${SWEEP_RANKS:-4}
runs=docs/bench/runs
mkdir -p "$runs"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
solve() { # ranks report-name args...
  local n=$1 name=$2
  shift 2
  echo "bench: $n ranks, $name" >&2
  mpirun --oversubscribe -n "$n" "$bin" render "$@" --max-shots "$SHOTS" --threshold 0 --width 0 \
    --report "$runs/$name.json" >/dev/null
}
for scene in $SCENES; do
  for n in $RANKS; do
    for ex in hemispheres form-factors sparse; do
      # One rank exchanges nothing: one run stands for all three.
      if [ "$n" = 1 ] && [ "$ex" != hemispheres ]; then continue; fi
      solve "$n" "$scene-n$n-$ex" "$scene" --exchange "$ex"
    done
  done
done
for res in 128x512 160x640 192x768; do
  solve "$SWEEP_RANKS" "sweep-res-$res" "$SWEEP_SCENE" --resolution "$res"
done
for tile in 1x1 4x4 16x8 64x32; do
  solve "$SWEEP_RANKS" "sweep-tile-$tile" "$SWEEP_SCENE" --tile "$tile"
done
target/release/radiosity-lab bench-report "$runs"/*.json --out docs/bench
