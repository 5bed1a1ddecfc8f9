#!/usr/bin/env bash
# End-to-end test of `flsh simulate` with a ROM avatar: a tiny soft walker (600 vertices, a
# coarse tet mesh, 12 handles, a small elastic cubature, exact inertia) next to a skeleton
# walker, a few steps. Checks the stderr report of the reduced data (handles, cubatures, cache),
# the reduced state (144 + 3·handles values) and the per-frame maximum displacement in
# states.npz, a sheet.png where the ROM avatar is coloured by displacement, the cache hit of a
# second run, `flsh avatar --soft rom`, and clear errors (exit code 2, nothing written) for bad
# ROM keys.
# Usage: simulate_rom_cli.sh FLSH_BINARY WORK_DIR
set -euo pipefail
flsh=$1
work=$2
here=$(cd "$(dirname "$0")" && pwd)  # for sheet_colours.py
rm -rf "$work" && mkdir -p "$work" && cd "$work"
py=/usr/bin/python3
fail() { echo "FAIL: $*" >&2; exit 1; }

# 0.1 s at h = 1/30: 3 steps, 4 saved frames, the first and the last on the sheet.
cat > rom.json <<'JSON'
{
  "time_step": 0.03333333333333333,
  "duration": 0.1,
  "newton": {"reduced_gradient_tolerance": 1e-6},
  "avatars": [
    {"name": "rigid", "vertices": 600, "motion": "builtin:walk", "motion_seconds": 0.5},
    {"name": "soft", "vertices": 600, "simulation": "rom", "resolution": 0.3, "handles": 12,
     "elastic_cubature": 40, "inertial_cubature": 0,
     "motion": "builtin:walk", "motion_seconds": 0.5, "offset": [1.2, 0, 0]}
  ],
  "colliders": [{"name": "ground", "type": "plane", "point": [0, -0.955, 0]}],
  "outputs": {"dir": "out", "ply": false, "gltf": false, "png_frames": 2}
}
JSON
"$flsh" simulate rom.json --cache cache >run.log 2>run.err || { cat run.err; fail "rom scene"; }
grep -q "building the volumetric body and the reduced basis of avatar 'soft'" run.err ||
  { cat run.err; fail "stderr should say the reduced basis is built"; }
grep -Eq "avatar 'soft' \(rom\): 12 handles, basis [0-9]+ nonzeros; elastic cubature [0-9]+ tets, held-out error [0-9.]+ %; inertial cubature off \(exact\); reduced data cache: miss" run.err ||
  { cat run.err; fail "stderr should report the reduced data (12 handles, cubatures, cache miss)"; }
grep -q "'rigid' (rom)" run.err && fail "the skeleton avatar has no reduced data line"
[ -n "$(ls -A cache)" ] || fail "--cache: nothing stored in cache/"
grep -q "3 steps" run.log || { cat run.log; fail "summary should count 3 steps"; }
grep -q "0 unconverged" run.log || { cat run.log; fail "every step should converge"; }
grep -q "avatar 'soft' (rom): max soft-tissue displacement |u| " run.log ||
  { cat run.log; fail "per-avatar maximum displacement line"; }
grep -q "'rigid' (rom)\|'rigid' (fem)" run.log && fail "the skeleton avatar has no displacement line"
scale=$(sed -n 's/.*sheet.png colours soft avatars by |u| (viridis): 0 mm dark purple to \([0-9.]*\) mm yellow.*/\1/p' run.log)
[ -n "$scale" ] || { cat run.log; fail "the sheet's colour scale should be printed"; }

$py - "$scale" "$here" <<'PY'
import sys
import numpy as np
sys.path.insert(0, sys.argv[2])
from sheet_colours import count_sheet_pixels
scale_mm = float(sys.argv[1])
d = np.load("out/states.npz")
T, H = 4, 12
assert d["rigid_states"].shape == (T, 144), d["rigid_states"].shape
assert "rigid_max_displacement_mm" not in d.files and "rigid_displacements" not in d.files
states = d["soft_states"]
assert states.shape == (T, 144 + 3 * H), states.shape  # bones, then z_h per handle
z = states[:, 144:].reshape(T, H, 3)  # m
m = d["soft_max_displacement_mm"]
assert m.shape == (T,) and np.isfinite(m).all() and (m >= 0).all(), m
assert m.max() > 0, "the soft tissue should move while walking: max displacement %s mm" % m
# The surface vertices' displacements: their norms' maximum is the recorded maximum.
disp = d["soft_displacements"]
assert disp.shape == (T, d["soft_vertices"].shape[1], 3), disp.shape
np.testing.assert_allclose(1000 * np.linalg.norm(disp, axis=2).max(axis=1), m, rtol=1e-12)
# Every handle is a surface vertex whose u is its z_h: the surface maximum is at least max |z|.
assert (m >= 1000 * np.linalg.norm(z, axis=2).max(axis=1) - 1e-9).all(), (m, z)
# The sheet shows frames 0 and 3 with one robust scale: the 99th percentile of their surface
# |u| (issue 29), so at most their larger maximum (printed with 3 decimals) and above 0.
assert 0 < scale_mm <= max(m[0], m[-1]) + 1e-3 + 1e-9, (scale_mm, m)
assert d["soft_vertices"].shape == (T, 600, 3) and np.isfinite(d["soft_vertices"]).all()
# The ROM surface differs from pure skinning: same motion, offset by 1.2 m along x.
moved = np.abs(d["soft_vertices"][-1] - d["rigid_vertices"][-1] - [1.2, 0, 0]).max()
assert moved > 1e-4, moved

rgb, coloured, skin = count_sheet_pixels("out/sheet.png")
h, w = rgb.shape[:2]
assert coloured > 500, "only %d displacement-coloured pixels" % coloured
assert skin > 500, "only %d skin-coloured pixels" % skin
print("rom sheet: %d x %d, %d coloured and %d skin pixels, max |u| %.3f mm"
      % (w, h, coloured, skin, m.max()))
PY

# A second run reads the volumetric body and the reduced data from the cache.
"$flsh" simulate rom.json --cache cache --out out_hit --duration 0.04 >hit.log 2>hit.err ||
  { cat hit.err; fail "second run"; }
grep -q "avatar 'soft': .* cache: hit" hit.err || { cat hit.err; fail "volumetric body: cache hit"; }
grep -q "avatar 'soft' (rom): .* reduced data cache: hit" hit.err ||
  { cat hit.err; fail "reduced data: cache hit"; }
"$flsh" simulate rom.json --no-cache --out out_off --duration 0.04 >off.log 2>off.err ||
  { cat off.err; fail "--no-cache run"; }
grep -q "reduced data cache: off" off.err || { cat off.err; fail "--no-cache should be reported"; }

# The default reduced solver preconditions CG with a lagged factor; "newton.reduced_lagged"
# reaches it: without the lag every iteration factors and no PCG runs.
grep -Eq "\([0-9.]+ factorizations, [1-9][0-9.]* PCG iterations\)" run.log ||
  { cat run.log; fail "the ROM scene should run PCG on the lagged factor"; }
sed 's/"newton": {"reduced_gradient_tolerance": 1e-6}/"newton": {"reduced_gradient_tolerance": 1e-6, "reduced_lagged": {"enabled": false}}/' \
  rom.json > nolag.json
grep -q '"reduced_lagged"' nolag.json || fail "nolag.json: the substitution did not apply"
"$flsh" simulate nolag.json --cache cache --out out_nolag >nolag.log 2>nolag.err ||
  { cat nolag.err; fail "scene with reduced_lagged.enabled = false"; }
grep -Eq "\([0-9.]+ factorizations, 0.0 PCG iterations\)" nolag.log ||
  { cat nolag.log; fail "reduced_lagged.enabled = false: no PCG expected"; }

# `flsh avatar --soft rom`: JSON statistics of the reduced data (the volumetric body cached).
"$flsh" avatar --model synthetic:600 --soft rom --resolution 0.3 --handles 12 \
  --elastic-cubature 40 --inertial-cubature 30 --cache cache >avatar.json 2>avatar.err ||
  { cat avatar.err; fail "flsh avatar --soft rom"; }
$py - <<'PY'
import json
s = json.load(open("avatar.json"))
r = s["reduced"]
assert s["soft"] == "rom" and r["handles"] == 12 and r["dofs"] == 144 + 36, r
assert r["basis_nonzeros"] >= 12 and r["basis_converged"], r
for name in ("elastic_cubature", "inertial_cubature"):
    c = r[name]
    assert c["enabled"] and 1 <= c["tets"] <= (40 if name.startswith("e") else 30), (name, c)
    assert 0 <= c["held_out_error"] < 1 and c["weight_sum"] > 0, (name, c)
assert r["inertial_cubature"]["rigid_motion_error"] > 0, r["inertial_cubature"]
assert s["cache"]["shape"] == "hit" and s["cache"]["reduced"] == "miss", s["cache"]
assert s["seconds"]["reduced_total"] > 0, s["seconds"]
assert r["surface_partition_of_unity"] is False, r
PY
# A basis with modes: the scene keys and `flsh avatar --basis`.
sed 's/"handles": 12,/"basis": "modes", "vibration_modes": 3, "modal_columns": 12,/' rom.json > modes.json
grep -q '"basis": "modes"' modes.json || fail "modes.json: the substitution did not apply"
"$flsh" simulate modes.json --cache cache --out out_modes >modes.log 2>modes.err ||
  { cat modes.err; fail "scene with a modal basis"; }
grep -Eq "avatar 'soft' \(rom\): 12 modes; elastic cubature" modes.err ||
  { cat modes.err; fail "stderr should report the 12 modes"; }
grep -q "0 unconverged" modes.log || { cat modes.log; fail "modes: every step should converge"; }
$py - <<'PY'
import numpy as np
d = np.load("out_modes/states.npz")
assert d["soft_states"].shape == (4, 144 + 12), d["soft_states"].shape  # bones, then the modes
assert d["soft_max_displacement_mm"].max() > 0
PY
"$flsh" avatar --model synthetic:600 --soft rom --resolution 0.3 --basis modes+handles \
  --handles 6 --vibration-modes 3 --modal-columns 12 --elastic-cubature 40 \
  --inertial-cubature 30 --cache cache >avatar_modes.json 2>avatar_modes.err ||
  { cat avatar_modes.err; fail "flsh avatar --basis modes+handles"; }
$py - <<'PY'
import json
r = json.load(open("avatar_modes.json"))["reduced"]
assert r["basis"] == "modes+handles" and r["handles"] == 6 and r["modes"] == 12, r
assert r["dofs"] == 144 + 18 + 12, r
PY
if "$flsh" avatar --model synthetic:600 --soft rom --basis mode >/dev/null 2>bad.err; then
  fail "--basis mode accepted"
fi
grep -q "basis kind 'mode', expected one of 'handles', 'modes', 'modes+handles'" bad.err ||
  { cat bad.err; fail "--basis mode: message"; }
# The default basis is the modal one; --handles without --basis chooses the handle basis (as
# "handles" without "basis" in a scene file), handles with the modal basis alone are an error.
"$flsh" avatar --model synthetic:600 --soft rom --resolution 0.3 --elastic-cubature 40 \
  --inertial-cubature 30 --cache cache >avatar_default.json 2>avatar_default.err ||
  { cat avatar_default.err; fail "flsh avatar --soft rom with the default basis"; }
$py - <<'PY'
import json
r = json.load(open("avatar_default.json"))["reduced"]
assert r["basis"] == "modes" and r["handles"] == 0 and r["modes"] == 72, r
PY
expect_cli_error() {  # expect_cli_error MESSAGE ARGS...
  local message=$1
  shift
  set +e
  "$flsh" avatar --model synthetic:600 --soft rom "$@" >/dev/null 2>bad.err
  local rc=$?
  set -e
  [ "$rc" -eq 2 ] || { cat bad.err; fail "exit code $rc (expected 2) for: $*"; }
  grep -qF -- "$message" bad.err || { cat bad.err; fail "message should contain: $message"; }
}
expect_cli_error "--handles: not used by --basis modes" --basis modes --handles 5
expect_cli_error "--vibration-modes and --modal-columns: only for --basis modes or modes+handles (--handles without --basis chooses the handle basis)" \
  --handles 5 --vibration-modes 3
expect_cli_error "--vibration-modes and --modal-columns: only for --basis modes or modes+handles" \
  --basis handles --modal-columns 12

# The realtime preset: the modal basis 12:24, 100-tet cubatures and a budget of 3 Newton
# iterations per step, whose end is reported as such and not as a failure.
cat > realtime.json <<'JSON'
{
  "preset": "realtime",
  "time_step": 0.03333333333333333,
  "duration": 0.3,
  "ground": "auto",
  "avatars": [{"name": "soft", "vertices": 600, "simulation": "rom", "resolution": 0.3,
               "motion": "builtin:walk", "motion_seconds": 0.5}],
  "outputs": {"dir": "out_realtime", "ply": false, "gltf": false, "png": false}
}
JSON
"$flsh" simulate realtime.json --cache cache >realtime.log 2>realtime.err ||
  { cat realtime.err; fail "scene with the realtime preset"; }
grep -Eq "avatar 'soft' \(rom\): 24 modes; elastic cubature [0-9]+ tets" realtime.err ||
  { cat realtime.err; fail "realtime: stderr should report the 24 modes"; }
grep -Eq "3\.00 Newton iterations/step .* 0 unconverged, [0-9]+ at the budget of 3 iterations" realtime.log ||
  { cat realtime.log; fail "realtime: 3 iterations per step, the budget reported, none unconverged"; }
$py - <<'PY'
import numpy as np
d = np.load("out_realtime/states.npz")
assert d["soft_states"].shape == (10, 144 + 24), d["soft_states"].shape
assert np.isfinite(d["soft_states"]).all() and d["soft_max_displacement_mm"].max() > 0
PY
"$flsh" avatar --model synthetic:600 --soft rom --resolution 0.3 --preset realtime \
  --inertial-cubature 30 --cache cache >avatar_rt.json 2>avatar_rt.err ||
  { cat avatar_rt.err; fail "flsh avatar --preset realtime"; }
$py - <<'PY'
import json
r = json.load(open("avatar_rt.json"))["reduced"]
assert r["basis"] == "modes" and r["modes"] == 24 and r["handles"] == 0, r
assert 1 <= r["elastic_cubature"]["tets"] <= 100 and 1 <= r["inertial_cubature"]["tets"] <= 30, r
PY
expect_cli_error "flsh avatar: error: --preset: unknown preset 'fast', expected 'none' or 'realtime'" \
  --preset fast
if "$flsh" avatar --model synthetic:600 --soft fem --preset realtime >/dev/null 2>bad.err; then
  fail "--preset accepted with --soft fem"
fi
grep -q "only for --soft rom" bad.err || { cat bad.err; fail "--preset with fem: message"; }

# --partition-of-unity: another basis (its own cache entry) of the same size.
"$flsh" avatar --model synthetic:600 --soft rom --resolution 0.3 --handles 12 \
  --elastic-cubature 40 --inertial-cubature 30 --partition-of-unity --cache cache \
  >avatar_pou.json 2>avatar_pou.err || { cat avatar_pou.err; fail "flsh avatar --partition-of-unity"; }
$py - <<'PY'
import json
r = json.load(open("avatar_pou.json"))["reduced"]
assert r["surface_partition_of_unity"] is True and r["handles"] == 12, r
assert json.load(open("avatar_pou.json"))["cache"]["reduced"] == "miss", r
PY
if "$flsh" avatar --model synthetic:600 --soft fem --partition-of-unity >/dev/null 2>bad.err; then
  fail "--partition-of-unity accepted with --soft fem"
fi
grep -q "only for --soft rom" bad.err || { cat bad.err; fail "--partition-of-unity with fem: message"; }
if "$flsh" avatar --model synthetic:600 --soft fem --handles 5 >/dev/null 2>bad.err; then
  fail "--handles accepted with --soft fem"
fi
grep -q "only for --soft rom" bad.err || { cat bad.err; fail "--handles with fem: message"; }

# Bad ROM settings: exit code 2, a message naming file, key and expectation, nothing written.
expect_error() {  # expect_error MESSAGE JSON
  printf '%s\n' "$2" > bad.json
  rm -rf out_bad
  set +e
  "$flsh" simulate bad.json --out out_bad --cache cache >bad.log 2>bad.err
  local rc=$?
  set -e
  [ "$rc" -eq 2 ] || { cat bad.err; fail "exit code $rc (expected 2) for: $2"; }
  grep -qF "$1" bad.err || { cat bad.err; fail "message should contain: $1"; }
  [ ! -e out_bad ] || fail "output written for a bad scene: $2"
}
expect_error 'bad.json: avatars[0].handles: only for "simulation": "rom" (this avatar is "fem"' \
  '{"avatars": [{"vertices": 600, "simulation": "fem", "handles": 12}]}'
expect_error 'bad.json: avatars[0].elastic_cubature: expected a number of sample tets in [0, 10000000]' \
  '{"avatars": [{"vertices": 600, "simulation": "rom", "elastic_cubature": -5}]}'
expect_error 'bad.json: avatars[0].handles: expected a number, got string "12"' \
  '{"avatars": [{"vertices": 600, "simulation": "rom", "handles": "12"}]}'
expect_error 'bad.json: avatars[0].handles: not used by "basis": "modes"' \
  '{"avatars": [{"vertices": 600, "simulation": "rom", "basis": "modes", "handles": 12}]}'
expect_error 'bad.json: newton.reduced_gradient_tolerance: expected 0 < value <= 1' \
  '{"newton": {"reduced_gradient_tolerance": -1}, "avatars": [{"vertices": 600}]}'
# More handles than the body's soft-tissue surface vertices: found when the avatar is built.
expect_error "bad.json: avatars[0] ('big', \"rom\"): buildReducedData: ReducedSettings::num_handles = 5000, expected at most the" \
  '{"avatars": [{"name": "big", "vertices": 600, "simulation": "rom", "resolution": 0.3, "handles": 5000}]}'

echo "simulate_rom_cli: all checks passed"
