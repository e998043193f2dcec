#!/usr/bin/env bash
# Folding sheets (docs/semi-rigid-and-constraints.md, "A folding sheet ran away in one
# cycle"): sheets pinned at their corners whose centre normal is asked to turn over, 300
# cycles each at periods from 0.40 to 0.60 T_max. Per sheet: the runs that exited non-zero
# (the CLI's runaway guard stops a run with exit 3), the runs whose energy passed
# 100 J and 1000 J, the highest energy, the runs with a cycle taken again in more steps,
# the runs whose normal stopped (its ring lost pi rad of its way) and, of those, the runs
# whose energy rose more than 5 % above its value at the end of the cycle it stopped in,
# with the largest such rise (highest energy after the stop over the energy at it).
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
printf '%-72s %5s %6s %6s %7s %10s %8s %8s %9s %6s\n' sheet runs failed ">100J" ">1000J" \
  "highest J" retaken stopped "rose>5%" "most"
for sheet in "${sheets[@]}"; do
  over100=0 over1000=0 highest=0 retaken=0 stopped=0 rose=0 most=1 failed=0
  for ((k = 0; k < periods; ++k)); do
    ratio=$(awk -v k="$k" -v n="$periods" 'BEGIN { printf "%.4f", 0.40 + 0.20 * k / (n - 1) }')
    rm -f "$work"/run.*
    # shellcheck disable=SC2086
    if ! "$zsculpt" simulate $sheet --angular-stiffness 0.5 --steps 300 --dt-ratio "$ratio" \
      --csv "$work/run.csv" --json > "$work/run.json" 2> "$work/run.err"; then
      failed=$((failed + 1))  # diverged (exit 3) or worse: counted, and its CSV if any read
      [[ -f $work/run.csv ]] || continue
    fi
    peak=$(awk -F, 'NR > 1 && $5 > m { m = $5 } END { printf "%.6g", m + 0 }' "$work/run.csv")
    awk -v p="$peak" 'BEGIN { exit !(p > 100) }' && over100=$((over100 + 1))
    awk -v p="$peak" 'BEGIN { exit !(p > 1000) }' && over1000=$((over1000 + 1))
    highest=$(awk -v a="$highest" -v b="$peak" 'BEGIN { print (b > a ? b : a) }')
    grep -q '"retaken_steps": [1-9]' "$work/run.json" && retaken=$((retaken + 1))
    # The stop is warned with the time its cycle started: its end is the first row after.
    stop=$(sed -n 's/.*normal constraint at vertex [0-9]* stopped at t = \([0-9.]*\) s.*/\1/p' \
      "$work/run.err" | head -n 1)
    if [[ -n $stop ]]; then
      stopped=$((stopped + 1))
      ratio=$(awk -F, -v t="$stop" 'NR > 1 && $2 > t + 1e-6 {  # t has 6 decimals
          if (!seen) { at = $5; seen = 1 } if ($5 > m) m = $5 }
        END { printf "%.6g", seen ? m / at : 1 }' "$work/run.csv")
      awk -v r="$ratio" 'BEGIN { exit !(r > 1.05) }' && rose=$((rose + 1))
      most=$(awk -v a="$most" -v b="$ratio" 'BEGIN { print (b > a ? b : a) }')
    fi
  done
  printf '%-72s %5d %6d %6d %7d %10.4g %8d %8d %9d %6.3g\n' "$sheet" "$periods" "$failed" \
    "$over100" "$over1000" "$highest" "$retaken" "$stopped" "$rose" "$most"
done
