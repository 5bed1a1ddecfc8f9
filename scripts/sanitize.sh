#!/usr/bin/env bash
# Builds flsh and its C++ tests with AddressSanitizer + UndefinedBehaviorSanitizer (leak checks
# on) and runs them through ctest: every GoogleTest suite and the command-line tests. The Python
# suite is left out: an instrumented extension module needs the sanitizer runtime preloaded into
# the interpreter, which would test the interpreter too.
# Usage: bash scripts/sanitize.sh [BUILD_DIR] [extra ctest arguments, e.g. -R solve]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$root/build-sanitize}
shift || true
jobs=$(nproc 2>/dev/null || echo 2)
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DFLSH_SANITIZE=address,undefined -DFLSH_PYTHON=OFF -DFLSH_BENCHMARKS=OFF
cmake --build "$build" -j "$jobs"
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export LSAN_OPTIONS=suppressions=$root/scripts/sanitize.supp
ctest --test-dir "$build" --output-on-failure -j "$jobs" "$@"
