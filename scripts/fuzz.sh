#!/usr/bin/env bash
# Builds the libFuzzer targets (fuzz/) with clang and runs each for a bounded time, seeded
# from tests/fuzz_corpus/<target>/ (docs/reliability.md). New interesting inputs go to a
# work corpus in the build folder, never into the source tree; a crash, leak, timeout or
# sanitizer report stops that target and leaves its input as <build>/artifacts/<target>/*.
#
#   scripts/fuzz.sh [TARGET...]        TARGET: scene mesh state cli (default: all four)
#
# Environment: FUZZ_SECONDS (default 60 per target), FUZZ_BUILD_DIR (default build-fuzz),
# FUZZ_JOBS (build jobs, default 2), FUZZ_ARGS (extra libFuzzer flags), FUZZ_NO_BUILD=1
# (run the targets as they are built).
# Needs clang, libclang-rt-14-dev and libomp-dev: scripts/install-deps.sh --reliability.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build="${FUZZ_BUILD_DIR:-$root/build-fuzz}"
seconds="${FUZZ_SECONDS:-60}"
jobs="${FUZZ_JOBS:-2}"
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(scene mesh state cli)

for t in "${targets[@]}"; do
  case "$t" in scene|mesh|state|cli) ;; *) echo "fuzz: error: $t: unknown target (scene mesh state cli)" >&2; exit 2 ;; esac
done

if [ "${FUZZ_NO_BUILD:-0}" != 1 ]; then
  CC=clang CXX=clang++ cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DZSCULPT_BUILD_FUZZERS=ON -DZSCULPT_BUILD_TESTS=OFF -DZSCULPT_BUILD_BENCHMARKS=OFF \
    -DZSCULPT_WERROR=OFF >/dev/null
  cmake --build "$build" -j "$jobs" --target "${targets[@]/#/fuzz_}"
fi

# One OpenMP thread: the fuzzers measure inputs, not speed, and stay within one core.
export OMP_NUM_THREADS=1
# UBSan reports are fatal (fuzz/flags.cmake); ASan's leak check runs at each input's end.
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:allocator_may_return_null=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
# Assimp 5.2 leaks a few KB on some malformed files (e.g. a bad number in an ASCII STL:
# tests/regressions/mesh/stl_ascii_bad_number_assimp_leak); leaks inside it are not ours.
mkdir -p "$build"
printf 'leak:libassimp.so\n' >"$build/lsan.supp"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$build/lsan.supp:print_suppressions=0}"
failed=()
for t in "${targets[@]}"; do
  work="$build/corpus/$t"
  artifacts="$build/artifacts/$t"
  mkdir -p "$work" "$artifacts"
  echo "fuzz: $t for ${seconds} s" >&2
  # In fork mode with -ignore_crashes libFuzzer exits 0 after findings: new artifacts count.
  stamp="$build/.fuzz_$t.start"
  touch "$stamp"
  # -rss_limit_mb: assimp may legitimately take a few hundred MB; a runaway is a finding.
  # -timeout: one input taking longer than 10 s is a hang.
  if ! "$build/fuzz/fuzz_$t" "$work" "$root/tests/fuzz_corpus/$t" \
      -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -max_len=65536 \
      -artifact_prefix="$artifacts/" -print_final_stats=1 ${FUZZ_ARGS:-} \
      >"$build/fuzz_$t.log" 2>&1; then
    failed+=("$t")
    echo "fuzz: $t FAILED: see $build/fuzz_$t.log and $artifacts/" >&2
  elif [ -n "$(find "$artifacts" -type f -newer "$stamp" -print -quit)" ]; then
    failed+=("$t")
    echo "fuzz: $t left new inputs in $artifacts/ (crash, oom, timeout or leak): see $build/fuzz_$t.log" >&2
  fi
  grep -E "^(#[0-9]+.*DONE|stat::number_of_executed_units|stat::peak_rss_mb|Done [0-9]+ runs)" \
    "$build/fuzz_$t.log" | sed "s/^/fuzz: $t: /" >&2 || true
done
if [ ${#failed[@]} -ne 0 ]; then
  echo "fuzz: failures in ${failed[*]}: copy each artifact to tests/regressions/<target>/" >&2
  exit 1
fi
echo "fuzz: no crash, hang or leak in ${targets[*]} (${seconds} s each)" >&2
