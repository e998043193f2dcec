#!/usr/bin/env bash
# The smallest T / T_max (to about 1e-4) at which `zsculpt simulate` stops with exit
# status 3 (diverged) within 3000 steps, by bisection on [0.9, 2].
#   scripts/divergence_threshold.sh [ZSCULPT] -- MODEL FLAGS...
# e.g. scripts/divergence_threshold.sh build/zsculpt -- builtin:dodecahedron --mass 0.5 \
#        --stiffness 5 --angular-stiffness 0.5 --perturb 0.05 --seed 13 [--no-drift-filter]
set -euo pipefail
zsculpt=${1:-build/zsculpt}
shift || true
[ "${1:-}" = "--" ] && shift
if [ $# -eq 0 ]; then
  echo "usage: $0 [ZSCULPT] -- MODEL FLAGS..." >&2
  exit 2
fi
lo=0.9
hi=2.0
for _ in $(seq 1 14); do
  mid=$(awk -v a="$lo" -v b="$hi" 'BEGIN { printf "%.10f", (a + b) / 2 }')
  status=0
  "$zsculpt" simulate "$@" --dt-ratio "$mid" --steps 3000 --allow-unstable >/dev/null 2>&1 ||
    status=$?
  case $status in
    3) hi=$mid ;;
    0) lo=$mid ;;
    *) echo "$0: zsculpt simulate failed with status $status at --dt-ratio $mid" >&2; exit 1 ;;
  esac
done
echo "stable at $lo, diverged at $hi (T / T_max)"
