#!/usr/bin/env bash
# The full soak (docs/reliability.md): Torus-II at 0.95 T_max under a random storm of
# forces, torques, pins, drags and edits of stiffness, mass and rest length, for SOAK_CYCLES
# cycles (default 200000), then a shorter soak under valgrind's leak check. The bounded
# version of the same test runs in the suite (test_reliability, Soak.*); this script only
# lengthens it.
#
#   scripts/soak.sh
#
# Environment: SOAK_CYCLES (default 200000), SOAK_SEED (default 1), SOAK_RATIO (T / T_max,
# default 0.95), SOAK_DAMPING (kg/s per vertex, default 0), SOAK_KINDS (a comma list of
# force, torque, pin, drag, stiffness, mass, rest-length; default all), SOAK_SUBSTEP_STRAIN
# (SimulationSettings::substepStrain, default 0.2; 0 keeps one step per cycle),
# SOAK_VALGRIND_CYCLES (default 2000; 0 skips valgrind), ZSCULPT_BUILD_DIR (default
# build-rel), BUILD_JOBS (2).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build="${ZSCULPT_BUILD_DIR:-$root/build-rel}"
cycles="${SOAK_CYCLES:-200000}"
seed="${SOAK_SEED:-1}"
ratio="${SOAK_RATIO:-0.95}"
export ZSCULPT_SOAK_DAMPING="${SOAK_DAMPING:-0}"
[ -n "${SOAK_KINDS:-}" ] && export ZSCULPT_SOAK_KINDS="$SOAK_KINDS"
[ -n "${SOAK_SUBSTEP_STRAIN:-}" ] && export ZSCULPT_SOAK_SUBSTEP_STRAIN="$SOAK_SUBSTEP_STRAIN"
vg_cycles="${SOAK_VALGRIND_CYCLES:-2000}"

[ -f "$build/CMakeCache.txt" ] || cmake -S "$root" -B "$build" -DZSCULPT_BUILD_BENCHMARKS=OFF >/dev/null
cmake --build "$build" -j "${BUILD_JOBS:-2}" --target test_reliability
binary="$build/tests/test_reliability"

echo "soak: $cycles cycles, seed $seed, T = $ratio T_max, damping $ZSCULPT_SOAK_DAMPING kg/s" >&2
ZSCULPT_SOAK_CYCLES="$cycles" ZSCULPT_SOAK_SEED="$seed" ZSCULPT_SOAK_RATIO="$ratio" \
  /usr/bin/time -f "soak: wall %e s, max RSS %M KB" \
  "$binary" --gtest_filter='Soak.*' --gtest_brief=0

if [ "$vg_cycles" != 0 ]; then
  command -v valgrind >/dev/null || { echo "soak: error: valgrind is not installed (scripts/install-deps.sh --reliability)" >&2; exit 2; }
  echo "soak: $vg_cycles cycles under valgrind --leak-check=full" >&2
  # One OpenMP thread: libgomp's thread pool is reachable at exit, not leaked, but one
  # thread keeps valgrind's run short. Definite and indirect leaks fail the run.
  OMP_NUM_THREADS=1 ZSCULPT_SOAK_CYCLES="$vg_cycles" ZSCULPT_SOAK_SEED="$seed" \
    valgrind --leak-check=full --errors-for-leak-kinds=definite,indirect --error-exitcode=3 \
    "$binary" --gtest_filter='Soak.*'
fi
echo "soak: done" >&2
