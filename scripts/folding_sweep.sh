#!/usr/bin/env bash
# Folding sheets (docs/semi-rigid-and-constraints.md, "A folding sheet ran away in one
# cycle"): sheets pinned at their corners whose centre normal is asked to turn over, 300
# cycles each at periods from 0.40 to 0.60 T_max. Per sheet: the runs whose energy passed
# 100 J and 1000 J, the highest energy, and the runs with a cycle taken again in more steps.
#   scripts/folding_sweep.sh [BUILD_DIR] [PERIODS]   (PERIODS per sheet, default 201)
set -euo pipefail
build=${1:-build}
periods=${2:-201}
zsculpt="$build/zsculpt"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
sheets=(
  "builtin:grid:7 --pin 0 --pin 6 --pin 42 --pin 48 --pin-normal 24:0,0,-1"
  "builtin:grid:9 --pin 0 --pin 8 --pin 72 --pin 80 --pin-normal 40:0,0,-1"
  "builtin:grid:7 --pin 0 --pin 6 --pin 42 --pin 48 --pin-normal 24:0.3,0,-1"
)
printf '%-72s %6s %7s %8s %11s %7s\n' sheet runs ">100J" ">1000J" "highest J" retaken
for sheet in "${sheets[@]}"; do
  over100=0 over1000=0 highest=0 retaken=0
  for ((k = 0; k < periods; ++k)); do
    ratio=$(awk -v k="$k" -v n="$periods" 'BEGIN { printf "%.4f", 0.40 + 0.20 * k / (n - 1) }')
    # shellcheck disable=SC2086
    "$zsculpt" simulate $sheet --angular-stiffness 0.5 --steps 300 --dt-ratio "$ratio" \
      --csv "$work/run.csv" --json > "$work/run.json" 2> /dev/null || true
    peak=$(awk -F, 'NR > 1 && $5 > m { m = $5 } END { printf "%.6g", m + 0 }' "$work/run.csv")
    awk -v p="$peak" 'BEGIN { exit !(p > 100) }' && over100=$((over100 + 1))
    awk -v p="$peak" 'BEGIN { exit !(p > 1000) }' && over1000=$((over1000 + 1))
    highest=$(awk -v a="$highest" -v b="$peak" 'BEGIN { print (b > a ? b : a) }')
    grep -q '"retaken_steps": [1-9]' "$work/run.json" && retaken=$((retaken + 1))
  done
  printf '%-72s %6d %7d %8d %11.4g %7d\n' "$sheet" "$periods" "$over100" "$over1000" \
    "$highest" "$retaken"
done
