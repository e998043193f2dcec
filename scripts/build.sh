#!/usr/bin/env bash
# Configures and builds zsculpt (Release, warnings as errors) into ./build.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build="${ZSCULPT_BUILD_DIR:-$root/build}"
jobs="$(nproc 2>/dev/null || echo 2)"
cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
cmake --build "$build" -j "$jobs"
