#!/usr/bin/env bash
# End-to-end test of `flsh synth-body`, `flsh motion` and `flsh pose`, including bad input.
# Usage: pose_cli.sh FLSH_BINARY WORK_DIR
set -euo pipefail
flsh=$1
work=$2
rm -rf "$work" && mkdir -p "$work" && cd "$work"
py=/usr/bin/python3
fail() { echo "FAIL: $*" >&2; exit 1; }

"$flsh" synth-body --out body.npz --vertices 600 | tee synth.log
grep -q "600 vertices, 1196 faces" synth.log || fail "synth-body summary"
"$flsh" motion --name walk --seconds 0.5 --fps 20 --out walk.npz | grep -q "11 frames" || fail "motion summary"

"$flsh" pose --model body.npz --motion walk.npz --out posed.npz | tee pose.log
grep -q "11 frames" pose.log || fail "pose summary"
$py - <<'PY'
import numpy as np
d = np.load("posed.npz")
assert d["vertices"].shape == (11, 600, 3) and d["vertices"].dtype == np.float64, d["vertices"].shape
assert d["joints"].shape == (11, 24, 3) and d["joints"].dtype == np.float64
assert np.isfinite(d["vertices"]).all()
# The walk moves forward along +z: the last frame's pelvis is ahead of the first.
assert d["joints"][-1, 0, 2] > d["joints"][0, 0, 2] + 0.3
PY

# --betas overrides: a taller body (shape direction 0 is height) has a higher head.
"$flsh" pose --model body.npz --motion walk.npz --betas 2 --out tall.npz >/dev/null
$py -c "
import numpy as np
a = np.load('posed.npz')['joints']; b = np.load('tall.npz')['joints']
assert b[0, 15, 1] - b[0, 0, 1] > a[0, 15, 1] - a[0, 0, 1] + 0.01, (a[0,15], b[0,15])
"

# Bad input: clear message, non-zero exit, no output file.
expect_error() {  # expect_error PATTERN OUTFILE -- command...
  local pattern=$1 outfile=$2; shift 3
  if "$@" 2>err.log; then fail "expected failure: $*"; fi
  grep -q -- "$pattern" err.log || { cat err.log; fail "message should mention '$pattern'"; }
  [ ! -e "$outfile" ] || fail "partial output $outfile left behind"
}
expect_error "missing.npz" out1.npz -- "$flsh" pose --model missing.npz --motion walk.npz --out out1.npz
expect_error "not-a-number" out2.npz -- "$flsh" pose --model body.npz --motion walk.npz --betas 1,not-a-number --out out2.npz
$py -c "
import numpy as np
np.savez('bad_motion.npz', poses=np.zeros((5, 70)), trans=np.zeros((5, 3)), mocap_framerate=30.0)
np.savez('nan_motion.npz', poses=np.full((5, 72), np.nan), trans=np.zeros((5, 3)), mocap_framerate=30.0)
"
expect_error "poses" out3.npz -- "$flsh" pose --model body.npz --motion bad_motion.npz --out out3.npz
expect_error "NaN" out4.npz -- "$flsh" pose --model body.npz --motion nan_motion.npz --out out4.npz
head -c 1000 body.npz > truncated.npz
expect_error "truncated.npz" out5.npz -- "$flsh" pose --model truncated.npz --motion walk.npz --out out5.npz
expect_error "unknown built-in motion" out6.npz -- "$flsh" motion --name moonwalk --out out6.npz
echo "pose_cli: all checks passed"
