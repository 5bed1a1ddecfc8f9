#!/usr/bin/env bash
# End-to-end test of `flsh simulate` with an FEM avatar: a tiny soft walker (600 vertices, a
# coarse tet mesh) next to a skeleton walker, a few steps. Checks the soft-tissue state and the
# per-frame maximum displacement in states.npz, the printed colour scale, a sheet.png where the
# FEM avatar is coloured by displacement (viridis) and the skeleton one stays skin-coloured, and
# the avatar cache flags --cache / --no-cache.
# Usage: simulate_fem_cli.sh FLSH_BINARY WORK_DIR
set -euo pipefail
flsh=$1
work=$2
here=$(cd "$(dirname "$0")" && pwd)  # for sheet_colours.py
rm -rf "$work" && mkdir -p "$work" && cd "$work"
py=/usr/bin/python3
fail() { echo "FAIL: $*" >&2; exit 1; }

# The skeleton avatar comes first (it gets the skin tint of avatar 0), the FEM one 1.2 m to
# its left; 0.1 s at h = 1/30: 3 steps, 4 saved frames, the first and the last on the sheet.
cat > fem.json <<'EOF'
{
  "time_step": 0.03333333333333333,
  "duration": 0.1,
  "avatars": [
    {"name": "rigid", "vertices": 600, "motion": "builtin:walk", "motion_seconds": 0.5},
    {"name": "soft", "vertices": 600, "simulation": "fem", "resolution": 0.3,
     "motion": "builtin:walk", "motion_seconds": 0.5, "offset": [1.2, 0, 0]}
  ],
  "colliders": [{"name": "ground", "type": "plane", "point": [0, -0.955, 0]}],
  "outputs": {"dir": "out", "ply": false, "gltf": false, "png_frames": 2}
}
EOF
"$flsh" simulate fem.json --cache cache >run.log 2>run.err || { cat run.err; fail "fem scene"; }
grep -q "avatar 'soft': .* nodes (.* soft tissue), .* tets; cache: miss" run.err ||
  { cat run.err; fail "stderr should report the soft avatar's mesh and a cache miss"; }
[ -n "$(ls -A cache)" ] || fail "--cache: nothing stored in cache/"
grep -q "3 steps" run.log || { cat run.log; fail "summary should count 3 steps"; }
grep -q "avatar 'soft' (fem): max soft-tissue displacement |u| " run.log ||
  { cat run.log; fail "per-avatar maximum displacement line"; }
scale=$(sed -n 's/.*sheet.png colours soft avatars by |u| (viridis): 0 mm dark purple to \([0-9.]*\) mm yellow.*/\1/p' run.log)
[ -n "$scale" ] || { cat run.log; fail "the sheet's colour scale should be printed"; }
grep -q "'rigid' (fem)" run.log && fail "the skeleton avatar has no displacement line"

$py - "$scale" "$here" <<'PY'
import sys
import numpy as np
sys.path.insert(0, sys.argv[2])
from sheet_colours import count_sheet_pixels
scale_mm = float(sys.argv[1])
d = np.load("out/states.npz")
T = 4
assert d["rigid_states"].shape == (T, 144), d["rigid_states"].shape
assert "rigid_max_displacement_mm" not in d.files and "rigid_displacements" not in d.files
states = d["soft_states"]
assert states.shape[0] == T and states.shape[1] > 144 and (states.shape[1] - 144) % 3 == 0, states.shape
u = states[:, 144:].reshape(T, -1, 3)  # every soft-tissue node, m
m = d["soft_max_displacement_mm"]
assert m.shape == (T,) and np.isfinite(m).all() and (m >= 0).all(), m
# Surface vertices are a subset of the soft-tissue nodes: their maximum cannot exceed all nodes'.
assert (m <= 1000 * np.linalg.norm(u, axis=2).max(axis=1) + 1e-9).all(), (m, u)
assert m.max() > 0, "the soft tissue should move while walking: max displacement %s mm" % m
# The surface vertices' displacements: their norms' maximum is the recorded maximum.
disp = d["soft_displacements"]
assert disp.shape == (T, d["soft_vertices"].shape[1], 3), disp.shape
np.testing.assert_allclose(1000 * np.linalg.norm(disp, axis=2).max(axis=1), m, rtol=1e-12)
# The sheet shows frames 0 and 3 with one robust scale: the 99th percentile of their surface
# |u| (issue 29), so at most their larger maximum (printed with 3 decimals) and above 0.
assert 0 < scale_mm <= max(m[0], m[-1]) + 1e-3 + 1e-9, (scale_mm, m)
assert d["soft_vertices"].shape == (T, 600, 3) and np.isfinite(d["soft_vertices"]).all()

rgb, coloured, skin = count_sheet_pixels("out/sheet.png")
h, w = rgb.shape[:2]
assert h > 480, "no colour bar strip below the 480-pixel frames: %d rows" % h
assert coloured > 500, "only %d displacement-coloured pixels" % coloured
assert skin > 500, "only %d skin-coloured pixels" % skin
print("fem sheet: %d x %d, %d coloured and %d skin pixels, max |u| %.3f mm"
      % (w, h, coloured, skin, m.max()))
PY

# The cache: a second run reads the volumetric body; --no-cache neither reads nor writes it.
"$flsh" simulate fem.json --cache cache --out out_hit --duration 0.04 >hit.log 2>hit.err ||
  { cat hit.err; fail "second run"; }
grep -q "avatar 'soft': .* cache: hit" hit.err || { cat hit.err; fail "second run should hit the cache"; }
"$flsh" simulate fem.json --no-cache --out out_off --duration 0.04 >off.log 2>off.err ||
  { cat off.err; fail "--no-cache run"; }
grep -q "avatar 'soft': .* cache: off" off.err || { cat off.err; fail "--no-cache should be reported"; }
if "$flsh" simulate fem.json --cache cache --no-cache --out out_bad >/dev/null 2>bad.err; then
  fail "--cache with --no-cache accepted"
fi
grep -qi "excludes" bad.err || { cat bad.err; fail "--cache/--no-cache message"; }
[ ! -e out_bad ] || fail "output left behind for conflicting flags"

echo "simulate_fem_cli: all checks passed"
