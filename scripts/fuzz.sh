#!/usr/bin/env bash
# Builds the libFuzzer targets of the readers and runs each for a while (docs/design.md,
# "Fuzzing").
#
#   bash scripts/fuzz.sh [SECONDS] [TARGET...]
#
# SECONDS per target (default 60); TARGETs among fuzz_npz fuzz_scene_file fuzz_mesh
# fuzz_avatar_cache (default: all four, one after the other). The build directory (default
# build-sanitize/, FLSH_FUZZ_BUILD) is the sanitized suite's (scripts/sanitize.sh configures it:
# clang-14, ASan + UBSan, FLSH_FUZZ=ON), so one instrumented build serves both; only the fuzz
# targets are built here. Each run starts from the seeds in fuzz/corpus/TARGET/, the inputs that
# once crashed a reader (fuzz/regressions/TARGET/, also replayed by tests/io/fuzz_replay_test.cpp)
# and what earlier runs found, kept with the crash artefacts outside the source tree in
# FLSH_FUZZ_OUT (default ${TMPDIR:-/tmp}/flsh-fuzz/TARGET/). Per input: a 10 s timeout and a
# 2 GB RSS limit. Prints
# each target's executions and whether it found a crash; exits 1 if any run crashed, timed out
# or ran out of memory.
#
#   bash scripts/fuzz.sh --seeds    # rewrites fuzz/corpus/fuzz_avatar_cache/ with make_corpus
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
build=${FLSH_FUZZ_BUILD:-$root/build-sanitize}
out=${FLSH_FUZZ_OUT:-${TMPDIR:-/tmp}/flsh-fuzz}
jobs=${FLSH_FUZZ_JOBS:-2}
all_targets=(fuzz_npz fuzz_scene_file fuzz_mesh fuzz_avatar_cache)

configure() {
  # Configured (or reconfigured, if another compiler set it up) by the sanitizer script.
  if [ ! -f "$build/build.ninja" ] || ! grep -q '^FLSH_FUZZ:BOOL=ON$' "$build/CMakeCache.txt" ||
    ! grep -q '^CMAKE_CXX_COMPILER:[A-Z]*=.*clang++-14$' "$build/CMakeCache.txt"; then
    bash "$root/scripts/sanitize.sh" --configure "$build"
  fi
}

if [ "${1:-}" = "--seeds" ]; then
  configure
  cmake --build "$build" -j"$jobs" --target fuzz_make_corpus
  seeds=$(mktemp -d)
  "$build/bin/fuzz_make_corpus" "$seeds"
  mkdir -p "$root/fuzz/corpus/fuzz_avatar_cache"
  cp "$seeds"/*.npz "$root/fuzz/corpus/fuzz_avatar_cache/"
  rm -rf "$seeds"
  ls -l "$root/fuzz/corpus/fuzz_avatar_cache"
  exit 0
fi

seconds=${1:-60}
if ! [[ "$seconds" =~ ^[0-9]+$ ]] || [ "$seconds" -lt 1 ]; then
  echo "fuzz.sh: SECONDS must be a positive integer, got '$seconds'" >&2
  exit 2
fi
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=("${all_targets[@]}")
for t in "${targets[@]}"; do
  [[ " ${all_targets[*]} " == *" $t "* ]] || {
    echo "fuzz.sh: unknown target '$t' (known: ${all_targets[*]})" >&2
    exit 2
  }
done

configure
cmake --build "$build" -j"$jobs" --target "${targets[@]}"

failed=0
summary=()
for t in "${targets[@]}"; do
  mkdir -p "$out/$t/corpus" "$out/$t/artifacts"
  log="$out/$t/last_run.log"
  echo "== $t: ${seconds} s (corpus $out/$t/corpus, seeds fuzz/corpus/$t)"
  dict=()
  [ -f "$root/fuzz/$t.dict" ] && dict=(-dict="$root/fuzz/$t.dict")
  set +e
  seeds=("$root/fuzz/corpus/$t")
  [ -d "$root/fuzz/regressions/$t" ] && seeds+=("$root/fuzz/regressions/$t")
  "$build/bin/$t" "$out/$t/corpus" "${seeds[@]}" "${dict[@]}" \
    -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="$out/$t/artifacts/" >"$log" 2>&1
  status=$?
  set -e
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
  [ -n "$runs" ] || runs=$(sed -n 's/^#\([0-9]*\).*/\1/p' "$log" | tail -n 1)
  if [ "$status" -eq 0 ]; then
    summary+=("$t: ${runs:-?} executions in ${seconds} s, no crash")
  else
    failed=1
    what=$(grep -m 1 -E 'ERROR: libFuzzer|ERROR: [A-Za-z]+Sanitizer|runtime error|SUMMARY' "$log" || true)
    summary+=("$t: FAILED after ${runs:-?} executions (${what:-exit $status}); log $log, artefacts:")
    for a in "$out/$t/artifacts"/*; do [ -e "$a" ] && summary+=("    $a"); done
    tail -n 40 "$log" >&2
  fi
done

echo
printf '%s\n' "${summary[@]}"
exit "$failed"
