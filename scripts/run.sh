#!/usr/bin/env bash
# Quick start 1: install what is missing, build, and run the main job: the window where a
# display exists, the headless demo (frames and plots in ./zsculpt-demo/) otherwise.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bash "$root/scripts/install-deps.sh"
bash "$root/scripts/build.sh"
zsculpt="${ZSCULPT_BUILD_DIR:-$root/build}/zsculpt"
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ]; then
  exec "$zsculpt" "$@"
else
  echo "no display: running the headless demo (zsculpt demo)" >&2
  exec "$zsculpt" demo "$@"
fi
