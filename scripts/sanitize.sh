#!/usr/bin/env bash
# Builds flsh and its C++ tests with clang-14, AddressSanitizer + UndefinedBehaviorSanitizer (leak
# checks on), and runs them through ctest: every GoogleTest suite and the command-line tests. The
# Python suite is left out: an instrumented extension module needs the sanitizer runtime preloaded
# into the interpreter, which would test the interpreter too.
#
# The same build directory holds the readers' libFuzzer targets (FLSH_FUZZ=ON; scripts/fuzz.sh
# uses it too), so sanitizing and fuzzing cost one instrumented build, not two. clang rather than
# GCC: it compiles this code several times faster with the sanitizers on (body_forward.cpp: 110 s
# against 709 s here), and its UBSan also reports pointer arithmetic on null (GCC's did not see
# xxhash64(nullptr, 0)). -O1 with line tables, and without NDEBUG so that Eigen's index
# assertions abort like a sanitizer report.
#
# Usage: bash scripts/sanitize.sh [BUILD_DIR] [extra ctest arguments, e.g. -R solve]
#        bash scripts/sanitize.sh --configure [BUILD_DIR]   # configure only (scripts/fuzz.sh)
# BUILD_DIR defaults to build-sanitize/. A directory configured with another compiler is
# reconfigured from scratch.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
configure_only=0
if [ "${1:-}" = "--configure" ]; then
  configure_only=1
  shift
fi
build=${1:-$root/build-sanitize}
shift || true
jobs=$(nproc 2>/dev/null || echo 2)

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

started=$SECONDS
cmake --build "$build" -j "$jobs"
echo "== sanitize.sh: built in $((SECONDS - started)) s"
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export LSAN_OPTIONS=suppressions=$root/scripts/sanitize.supp
started=$SECONDS
status=0
ctest --test-dir "$build" --output-on-failure -j "$jobs" "$@" || status=$?
echo "== sanitize.sh: tests ran in $((SECONDS - started)) s"
exit "$status"
