#!/usr/bin/env bash
# The test suite under sanitizers (docs/reliability.md):
#   1. AddressSanitizer + UndefinedBehaviorSanitizer (+ LeakSanitizer) on the whole suite,
#      in build-asan;
#   2. ThreadSanitizer on the threading tests (solver thread, triple buffer), in build-tsan.
# Each build folder is removed after its run unless KEEP_BUILDS=1 (they are large), so
# at most one sanitizer build exists at a time.
#
#   scripts/sanitize.sh [asan|tsan]...     (default: both)
#
# Environment: SANITIZE_JOBS (build jobs, default 2), CTEST_ARGS (extra ctest flags),
# TSAN_TESTS (ctest -R regex of the threading tests).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
jobs="${SANITIZE_JOBS:-2}"
which=("$@")
[ ${#which[@]} -eq 0 ] && which=(asan tsan)
status=0

# No -Werror: GCC 12 at -O2 with sanitizers gives false -Wmaybe-uninitialized warnings
# (std::variant of editing commands in src/app/panels.cpp) that stop the build.
configure() {  # folder, sanitizers
  cmake -S "$root" -B "$1" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DZSCULPT_SANITIZE="$2" \
    -DZSCULPT_BUILD_BENCHMARKS=OFF -DZSCULPT_WERROR=OFF >/dev/null
}

# Findings are fatal and printed with a stack; LeakSanitizer runs at each test's exit.
# GL drivers (via OSMesa and GLX), GLFW and assimp leak by design: their reports are
# suppressed, ours are not (written next to the logs, build-sanitize-logs/).
# Mesa renders with softpipe here, not llvmpipe: llvmpipe's JIT (LLVM 15's MCJIT) frees
# with an operator that does not match its allocation, which ASan reports inside libLLVM
# in every offscreen test. softpipe is the same Mesa front end without the JIT.
export GALLIUM_DRIVER="${GALLIUM_DRIVER:-softpipe}"
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:detect_stack_use_after_return=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
logs="${SANITIZE_LOG_DIR:-$root/build-sanitize-logs}"
mkdir -p "$logs"
cat >"$logs/lsan.supp" <<'SUPP'
# Third-party leaks by design (never zsculpt's own code): Mesa's llvmpipe and OSMesa keep
# global state for the process's life, as do GLFW/X11 and fontconfig.
leak:libLLVM
leak:libgallium
leak:swrast_dri
leak:libOSMesa
leak:libglfw
leak:libX11
leak:libfontconfig
# assimp 5.2's importers leak on some malformed files (FuzzRegressions.Mesh, the corpus).
leak:libassimp
SUPP
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$logs/lsan.supp:print_suppressions=0}"
export TSAN_OPTIONS="${TSAN_OPTIONS:-halt_on_error=1:second_deadlock_stack=1}"

for w in "${which[@]}"; do
  case "$w" in
    asan)
      build="$root/build-asan"
      configure "$build" address,undefined
      cmake --build "$build" -j "$jobs"
      # The suite's own timeouts are for Release speed; sanitizers are several times slower.
      if ! ctest --test-dir "$build" --output-on-failure -j "$jobs" --timeout 1800 \
          -E '^Window\.|^Offscreen\.Reference' ${CTEST_ARGS:-} 2>&1 | tee "$logs/asan.log"; then status=1; fi
      # The reference images were rendered by llvmpipe, and softpipe's pixels differ (by 10 to
      # 18 levels on average): those two tests run on llvmpipe, with ASan's allocator-pairing
      # check off for LLVM's JIT (every other check on).
      if ! GALLIUM_DRIVER=llvmpipe ASAN_OPTIONS="$ASAN_OPTIONS:alloc_dealloc_mismatch=0" \
          ctest --test-dir "$build" --output-on-failure --timeout 1800 -R '^Offscreen\.Reference' \
          ${CTEST_ARGS:-} 2>&1 | tee -a "$logs/asan.log"; then status=1; fi
      # The window tests load the GLX driver, which Mesa unloads at exit before LeakSanitizer
      # runs: its one allocation it keeps (112 bytes) then has no module to be named by or
      # suppressed with. They also pick a brush centre from the depth buffer to llvmpipe's
      # precision, so they run on llvmpipe like the reference images. Every other ASan and
      # UBSan check stays on for them.
      if ! GALLIUM_DRIVER=llvmpipe ASAN_OPTIONS="$ASAN_OPTIONS:detect_leaks=0:alloc_dealloc_mismatch=0" \
          ctest --test-dir "$build" --output-on-failure \
          --timeout 1800 -R '^Window\.' ${CTEST_ARGS:-} 2>&1 | tee -a "$logs/asan.log"; then status=1; fi
      ;;
    tsan)
      build="$root/build-tsan"
      configure "$build" thread
      # GCC's libgomp is not built with ThreadSanitizer, so its barriers look like races:
      # the OpenMP loops inside a step run on one thread here; the solver thread, the
      # display and the triple buffer are what this run checks.
      export OMP_NUM_THREADS=1
      regex="${TSAN_TESTS:-TripleBuffer|SolverThread}"
      cmake --build "$build" -j "$jobs" --target test_app
      if ! ctest --test-dir "$build" --output-on-failure -j "$jobs" --timeout 1800 -R "$regex" \
          ${CTEST_ARGS:-} 2>&1 | tee "$logs/tsan.log"; then status=1; fi
      unset OMP_NUM_THREADS
      ;;
    *) echo "sanitize: error: $w: unknown (asan tsan)" >&2; exit 2 ;;
  esac
  [ "${KEEP_BUILDS:-0}" = 1 ] || rm -rf "$build"
done
exit $status
