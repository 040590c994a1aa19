#!/usr/bin/env bash
# The main job: install what is missing, build, and render a scene (default:
# the Cornell box) to out/<scene>.exr, out/<scene>.png and out/<scene>.json.
# Extra arguments go to `radiosity render` (see `radiosity render --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
scene="${1:-cornell}"
shift || true
cargo run --release --locked --bin radiosity -- render "$scene" --out-dir out "$@"
