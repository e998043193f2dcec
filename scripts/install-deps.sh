#!/usr/bin/env bash
# Installs the Debian 12 packages zsculpt needs to build, test and run
# (--reliability: also the fuzzing and leak-checking tools).
# Idempotent: quiet and quick when everything is already there.
set -euo pipefail

packages=(
  build-essential cmake pkg-config git clang-format
  libeigen3-dev
  libassimp-dev assimp-testmodels
  libgtest-dev libbenchmark-dev
  libosmesa6-dev libgl-dev libglfw3-dev libimgui-dev libstb-dev
  nlohmann-json3-dev libcli11-dev
  xvfb xauth
)
# Optional: `install-deps.sh --reliability` adds what scripts/fuzz.sh, sanitize.sh and
# soak.sh need (clang with libFuzzer and its OpenMP, valgrind); CI's install stays small.
if [ "${1:-}" = "--reliability" ]; then
  packages+=(clang libclang-rt-14-dev libomp-dev valgrind)
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then
    SUDO=sudo
  else
    echo "install-deps: error: missing packages (${missing[*]}) and not root; run as root" >&2
    exit 1
  fi
else
  SUDO=
fi

echo "install-deps: installing ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
