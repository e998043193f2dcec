#!/usr/bin/env bash
# Trajectory error of the default scheme with its drift filter (on for braced models) and
# with the kick filter alone (--no-drift-filter), against a small-step reference made with
# the kick filter (docs/solver.md section 6): Torus-I braced with angle springs, random
# start, 4 simulated seconds, largest position difference at the end.
#   scripts/trajectory_error.sh [BUILD_DIR]
set -euo pipefail
build=${1:-build}
zsculpt="$build/zsculpt"
model=(builtin:torus --mass 0.1 --angular-stiffness 0.5 --perturb 0.05 --seed 1)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
tmax=$("$zsculpt" info "${model[0]}" --mass 0.1 --angular-stiffness 0.5 --json |
  sed -n 's/.*"t_max": *\([0-9.eE+-]*\).*/\1/p')
run() {  # ratio, output, extra flags
  local steps dt
  steps=$(awk -v r="$1" -v t="$tmax" 'BEGIN { printf "%d", 4.0 / (r * t) + 0.5 }')
  dt=$(awk -v s="$steps" 'BEGIN { printf "%.17g", 4.0 / s }')
  "$zsculpt" simulate "${model[@]}" --dt "$dt" --steps "$steps" --state-out "$2" "${@:3}" \
    > /dev/null
}
difference() {  # largest |x - x_ref| over the positions
  paste -d, "$1" "$2" | awk -F, '$1 ~ /^[-0-9.]/ {
      for (k = 1; k <= 3; ++k) { d = $k - $(k + 6); if (d < 0) d = -d; if (d > m) m = d } }
    END { printf "%.3e", m }'
}
run 0.01 "$work/ref.csv" --no-drift-filter
printf '%-8s %-20s %-14s\n' "T/T_max" "--no-drift-filter" "default"
for ratio in 0.5 0.25 0.125 0.0625; do
  run "$ratio" "$work/k.csv" --no-drift-filter
  run "$ratio" "$work/d.csv"
  printf '%-8s %-20s %-14s\n' "$ratio" "$(difference "$work/k.csv" "$work/ref.csv")" \
    "$(difference "$work/d.csv" "$work/ref.csv")"
done
