#!/usr/bin/env bash
# Quick start 1: install what is missing, build, and run the main job: the window where a
# display exists, the headless demo (frames and plots in ./zsculpt-demo/) otherwise.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bash "$root/scripts/install-deps.sh"
bash "$root/scripts/build.sh"
zsculpt="${ZSCULPT_BUILD_DIR:-$root/build}/zsculpt"
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ] && "$zsculpt" --help | grep -q "^  open"; then
  exec "$zsculpt" "$@"
elif "$zsculpt" --help | grep -q "^  demo"; then
  exec "$zsculpt" demo "$@"
else
  exec "$zsculpt" info builtin:torus "$@"
fi
