#!/usr/bin/env bash
# Builds flsh and its C++ tests with clang-14, AddressSanitizer + UndefinedBehaviorSanitizer (leak
# checks on), and runs them: each GoogleTest executable of the chosen areas once (one process per
# executable, so that the fixtures an area shares, e.g. synthetic bodies, are built once: ctest's
# one process per test made the whole suite take hours under ASan), and the command-line tests
# (tests/cli, through ctest) when the area "cli" is chosen. The Python suite is left out: an instrumented extension module needs
# the sanitizer runtime preloaded into the interpreter, which would test the interpreter too.
#
# Areas (FLSH_SANITIZE_AREAS, the folders of tests/): by default those the CI runs, which hold
# every reader of files (format, io: npz/npy, meshes, scene files, the avatar cache, the fuzzers'
# regression inputs), the solvers, contact, the energy densities, rendering and the core (4 min
# on 2 cores); "all" adds body, volume, sim, diff, ceres and cli (hours: docs/design.md,
# "Sanitizers", has the times).
#
# The same build directory holds the readers' libFuzzer targets (FLSH_FUZZ=ON; scripts/fuzz.sh
# uses it too), so sanitizing and fuzzing cost one instrumented build, not two. clang rather than
# GCC: it compiles this code several times faster with the sanitizers on (body_forward.cpp: 110 s
# against 709 s here), and its UBSan also reports pointer arithmetic on null (GCC's did not see
# xxhash64(nullptr, 0)). -O1 with line tables, and without NDEBUG so that Eigen's index
# assertions abort like a sanitizer report.
#
# Usage: [FLSH_SANITIZE_AREAS="io format"|all] bash scripts/sanitize.sh [BUILD_DIR]
#        bash scripts/sanitize.sh --configure [BUILD_DIR]   # configure only (scripts/fuzz.sh)
# BUILD_DIR defaults to build-sanitize/. A directory configured with another compiler is
# reconfigured from scratch. Exits 1 if any test failed.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
configure_only=0
if [ "${1:-}" = "--configure" ]; then
  configure_only=1
  shift
fi
build=${1:-$root/build-sanitize}
jobs=$(nproc 2>/dev/null || echo 2)
ci_areas="core format contact energy render io solve"
areas=${FLSH_SANITIZE_AREAS:-$ci_areas}
if [ "$areas" = "all" ]; then
  areas="$ci_areas body volume ceres diff sim cli"
fi
for area in $areas; do
  [ -d "$root/tests/$area" ] || {
    echo "sanitize.sh: FLSH_SANITIZE_AREAS: no test folder tests/$area (known: $ci_areas body volume ceres diff sim cli, or all)" >&2
    exit 2
  }
done

command -v clang++-14 >/dev/null || {
  echo "sanitize.sh: clang++-14 not found (scripts/setup.sh installs clang-14 and libclang-rt-14-dev)" >&2
  exit 2
}
if [ -f "$build/CMakeCache.txt" ] &&
  ! grep -q '^CMAKE_CXX_COMPILER:[A-Z]*=.*clang++-14$' "$build/CMakeCache.txt"; then
  echo "sanitize.sh: $build was configured with another compiler; configuring it afresh"
  rm -rf "$build/CMakeCache.txt" "$build/CMakeFiles"
fi
flags="-O1 -gline-tables-only"
CC=clang-14 CXX=clang++-14 cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="$flags" -DCMAKE_C_FLAGS_RELWITHDEBINFO="$flags" \
  -DCMAKE_CXX_FLAGS=-Wno-unknown-warning-option \
  -DFLSH_SANITIZE=address,undefined -DFLSH_FUZZ=ON -DFLSH_TESTS=ON -DFLSH_NATIVE=OFF \
  -DFLSH_PYTHON=OFF -DFLSH_BENCHMARKS=OFF >/dev/null
[ "$configure_only" -eq 1 ] && exit 0

targets=(flsh_cli)
for area in $areas; do [ "$area" = cli ] || targets+=("flsh_test_$area"); done
started=$SECONDS
cmake --build "$build" -j "$jobs" --target "${targets[@]}"
echo "== sanitize.sh: built in $((SECONDS - started)) s (areas: $areas)"

export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export LSAN_OPTIONS=suppressions=$root/scripts/sanitize.supp
export FLSH_TEST_TMP=$build/test_tmp
mkdir -p "$FLSH_TEST_TMP"
status=0
summary=()
for area in $areas; do
  [ "$area" = cli ] && continue
  started=$SECONDS
  log="$build/test_tmp/sanitize_$area.log"
  if "$build/bin/flsh_test_$area" --gtest_brief=1 >"$log" 2>&1; then
    summary+=("$area: $(sed -n 's/^\[==========\] \([0-9]*\) tests.*/\1 tests/p' "$log" | tail -n 1) passed in $((SECONDS - started)) s")
  else
    status=1
    summary+=("$area: FAILED in $((SECONDS - started)) s (log $log)")
    tail -n 60 "$log" >&2
  fi
done
started=$SECONDS
if [[ " $areas " != *" cli "* ]]; then
  :
elif ctest --test-dir "$build" --output-on-failure -j "$jobs" -R '^cli\.' >"$build/test_tmp/sanitize_cli.log" 2>&1; then
  summary+=("cli: $(grep -c ' Passed ' "$build/test_tmp/sanitize_cli.log") tests passed in $((SECONDS - started)) s")
else
  status=1
  summary+=("cli: FAILED in $((SECONDS - started)) s (log $build/test_tmp/sanitize_cli.log)")
  tail -n 60 "$build/test_tmp/sanitize_cli.log" >&2
fi
echo "== sanitize.sh: under ASan + UBSan:"
printf '   %s\n' "${summary[@]}"
exit "$status"
