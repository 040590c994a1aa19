#!/usr/bin/env bash
# Installs what the renderer needs on Debian 12, only what is missing:
# lavapipe (Mesa's software Vulkan driver) and the Vulkan loader, Open MPI and
# libclang (for the MPI crate), pkgconf and Xvfb (for the viewer's tests),
# fontconfig and DejaVu fonts (benchmark charts), procps (kill and pgrep, for
# the fault tests).
# Safe to run again. Sourced by render.sh and test.sh.
set -euo pipefail

# Installs those of the given Debian packages that are missing (scripts
# that need more, such as bench-packets.sh, call it too).
install_missing() {
  local missing=() p sudo=""
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if ((${#missing[@]})); then
    echo "setup: installing ${missing[*]}" >&2
    if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  fi
}

install_missing mesa-vulkan-drivers libvulkan1 libopenmpi-dev openmpi-bin libclang-dev pkgconf xvfb \
  libfontconfig1-dev fonts-dejavu-core procps

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found: install Rust (https://rustup.rs) and run this again" >&2
  exit 1
fi

# Mesa's window-system code warns without a runtime directory; give it one.
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  export XDG_RUNTIME_DIR="/tmp/runtime-$(id -u)"
  mkdir -p -m 700 "$XDG_RUNTIME_DIR"
fi
