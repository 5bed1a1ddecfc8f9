#!/usr/bin/env bash
# Builds flsh (if needed) and runs every test: C++ (GoogleTest, CLI scripts, the installed
# package, the fuzzers' regression inputs) and Python (pytest), all through ctest, in BUILD_DIR
# (default build/). Two more stages run when asked for in FLSH_TEST_STAGES (default: suite):
#   sanitize  the C++ suite again under AddressSanitizer + UndefinedBehaviorSanitizer
#             (scripts/sanitize.sh, in build-sanitize/);
#   fuzz      each libFuzzer target of the readers for FLSH_FUZZ_SECONDS (default 30) seconds
#             (scripts/fuzz.sh, in build-fuzz/).
# Usage: [FLSH_TEST_STAGES=suite,sanitize,fuzz] bash scripts/test.sh [BUILD_DIR]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$root/build}
jobs=$(nproc 2>/dev/null || echo 2)
stages=",${FLSH_TEST_STAGES:-suite},"
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
