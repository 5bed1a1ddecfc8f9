#!/usr/bin/env bash
# Builds flsh (if needed) and runs every test, in three stages (FLSH_TEST_STAGES, default
# suite,sanitize,fuzz; CI runs all three):
#   suite     C++ (GoogleTest, CLI scripts, the installed package, the fuzzers' regression
#             inputs) and Python (pytest), all through ctest, in BUILD_DIR (default build/);
#   sanitize  the C++ tests of the areas holding the file readers, solvers, contact, energy
#             densities, rendering and core, again under AddressSanitizer +
#             UndefinedBehaviorSanitizer (scripts/sanitize.sh, in build-sanitize/;
#             FLSH_SANITIZE_AREAS=all for every area, the CLI tests included);
#   fuzz      each libFuzzer target of the readers for FLSH_FUZZ_SECONDS (default 30) seconds
#             (scripts/fuzz.sh, in the same build-sanitize/).
# Usage: [FLSH_TEST_STAGES=suite] bash scripts/test.sh [BUILD_DIR]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$root/build}
jobs=$(nproc 2>/dev/null || echo 2)
stages=",${FLSH_TEST_STAGES:-suite,sanitize,fuzz},"
started=$SECONDS

if [[ $stages == *,suite,* ]]; then
  echo "== test.sh: the suite (build: $build)"
  cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release
  cmake --build "$build" -j "$jobs"
  ctest --test-dir "$build" --output-on-failure -j "$jobs"
fi
if [[ $stages == *,sanitize,* ]]; then
  echo "== test.sh: the C++ suite under ASan + UBSan ($((SECONDS - started)) s so far)"
  bash "$root/scripts/sanitize.sh" "$root/build-sanitize"
fi
if [[ $stages == *,fuzz,* ]]; then
  echo "== test.sh: the readers' fuzz targets ($((SECONDS - started)) s so far)"
  bash "$root/scripts/fuzz.sh" "${FLSH_FUZZ_SECONDS:-30}"
fi
echo "== test.sh: done in $((SECONDS - started)) s"
