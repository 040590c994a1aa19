#!/usr/bin/env bash
# Installs what is missing, then runs the whole test suite under lavapipe
# (one release build shared by the library, the binary and the tests).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo test --release --locked --workspace "$@"
