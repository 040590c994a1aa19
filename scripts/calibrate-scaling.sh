#!/usr/bin/env bash
# Measurements the performance model (docs/scaling.md, `radiosity-lab scaling`)
# is calibrated and validated on. Every run is the paper's: 100 shots, no
# threshold, no image.
#
# - 1 rank pinned to one core (`taskset`) and 2 ranks bound one per core
#   (`mpirun --bind-to core`), one lavapipe thread each: the per-rank phase
#   times, bytes and counts the model is fitted to, for every exchange.
# - 4, 8 and 16 ranks oversubscribed on the two cores: wall times mean
#   nothing there, but each rank's process CPU seconds outside MPI calls
#   (report: parallel.per_rank[].cpu_seconds - mpi_cpu_seconds), its bytes
#   and its work counts do; the model's predictions are checked on them.
#
# Every run is made REPEAT times (default 2; files -rep2...); the model
# takes the fastest of each, by wall time on 1-2 ranks and by CPU beyond
# (neighbours on a shared machine only ever slow a run down).
#
#   SCENES="cubes-b1 classroom-c3" BIG="cubes-b3" scripts/calibrate-scaling.sh
#   RASTERISER=cpu RUNS=/tmp/cal-cpu/runs scripts/calibrate-scaling.sh
#
# Writes docs/scaling/runs/<scene>-<resolution>-n<ranks>-<exchange>.json,
# skipping runs already there (FORCE=1 redoes them), then fits the model
# (`radiosity-lab scaling`: docs/scaling/*.csv and the charts).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo build --release --locked --bin radiosity --bin radiosity-lab
# A copy, so a build during the runs cannot swap the binary under them.
bin=$(mktemp -d)/radiosity
cp target/release/radiosity "$bin"
SHOTS=${SHOTS:-100}
SCENES=${SCENES:-"cubes-b1 classroom-c1 classroom-c2 classroom-c3"}
BIG=${BIG:-"cubes-b2 cubes-b3"}
OVER=${OVER:-"4 8 16"}
OVER_BIG=${OVER_BIG:-"4 8"}
REPEAT=${REPEAT:-2}
# The ranks deal the bounds at every rank count (the model fits the deal's
# all-to-all as its own term; docs/notebook/ranks.md "Ranks"); DEAL=auto or off to compare.
DEAL=${DEAL:-on}
# Who draws the hemispheres (`--rasteriser`): the committed runs in
# docs/scaling/runs were made by the device (lavapipe), before the CPU
# drawing existed; RASTERISER=cpu (or auto, the default a render takes on
# lavapipe) for the current shot (docs/scaling.md "Drawn on the CPU").
RASTERISER=${RASTERISER:-device}
runs=${RUNS:-docs/scaling/runs}
mkdir -p "$runs"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 LP_NUM_THREADS=1
export OMPI_MCA_btl=${OMPI_MCA_btl:-self,vader,tcp}
# Batched shots (`--batch`, not the paper's method: each rank draws whole
# hemispheres for its turns of a batch) on these scenes, in batches of
# BATCH (at least the most ranks the model is read at: 64).
BATCH=${BATCH:-64}
BATCH_SCENES=${BATCH_SCENES:-"cubes-b1 classroom-c3 cubes-b2 cubes-b3"}
run() { # ranks scene resolution exchange [repeat] (exchange batches-K: --batch K)
  local n=$1 scene=$2 res=$3 ex=$4 rep=${5:-1}
  local out="$runs/$scene-$res-n$n-$ex.json"
  if [ "$rep" != 1 ]; then out="$runs/$scene-$res-n$n-$ex-rep$rep.json"; fi
  if [ -f "$out" ] && [ -z "${FORCE:-}" ]; then return; fi
  echo "calibrate: $scene $res, $n ranks, $ex ($rep)" >&2
  # --refine-shading 0: the mesh the committed runs were made on. The
  # shading criterion serves the camera image (these runs make none) and,
  # after the big scenes' short coarse pass, refines thousands of their
  # small faces (cubes-b1: 200 244 -> 296 580 elements).
  local exchange=(--exchange "$ex")
  case "$ex" in batches-*) exchange=(--exchange hemispheres --batch "${ex#batches-}") ;; esac
  # Every row is dealt before any is drawn (the pool of rows was taken out
  # on 2026-12-07: docs/mechanisms.md); the model replays older pooled
  # runs as they dealt.
  local args=(render "$scene" --resolution "$res" "${exchange[@]}" --max-shots "$SHOTS"
    --threshold 0 --width 0 --refine-shading 0 --deal-bounds "$DEAL" --rasteriser "$RASTERISER"
    --report "$out")
  if [ "$n" = 1 ]; then
    taskset -c 0 "$bin" "${args[@]}" >/dev/null 2>&1
  elif [ "$n" = 2 ]; then
    mpirun --bind-to core -n 2 -x LP_NUM_THREADS "$bin" "${args[@]}" >/dev/null 2>&1
  else
    mpirun --oversubscribe --bind-to none -n "$n" -x LP_NUM_THREADS "$bin" "${args[@]}" >/dev/null 2>&1
  fi
}
for rep in $(seq 1 "$REPEAT"); do
  for scene in $SCENES $BIG; do
    run 1 "$scene" 128x512 hemispheres "$rep"
    for ex in hemispheres form-factors sparse; do run 2 "$scene" 128x512 "$ex" "$rep"; done
  done
  # The paper's figure 12: B3 at a finer hemisphere.
  for n in 1 2; do run "$n" cubes-b3 192x768 hemispheres "$rep"; done
  for scene in $BATCH_SCENES; do
    for n in 1 2; do run "$n" "$scene" 128x512 "batches-$BATCH" "$rep"; done
  done
done
# Batched runs beyond 2 ranks twice too (the model takes the least CPU of
# each): a rank draws only a few whole rows a batch, so one noisy row
# moves its CPU seconds far more than a split shot's.
for rep in $(seq 1 "$REPEAT"); do
  for scene in $BATCH_SCENES; do
    over=$OVER
    case " $BIG " in *" $scene "*) over=$OVER_BIG ;; esac
    for n in $over; do run "$n" "$scene" 128x512 "batches-$BATCH" "$rep"; done
  done
done
# The other exchanges beyond 2 ranks twice as well (the least CPU kept):
# single runs left a point 10-20 % off the law on a noisy hour.
for rep in $(seq 1 "$REPEAT"); do
  for scene in $SCENES; do
    for n in $OVER; do run "$n" "$scene" 128x512 hemispheres "$rep"; done
    run 8 "$scene" 128x512 sparse "$rep"
  done
  # The big scenes beyond 2 ranks (each rank holds the whole scene: 8 ranks
  # of cubes-b3 take about 8 GB).
  for scene in $BIG; do
    for n in $OVER_BIG; do run "$n" "$scene" 128x512 hemispheres "$rep"; done
  done
done
target/release/radiosity-lab scaling --runs "$runs" --out "$(dirname "$runs")"
