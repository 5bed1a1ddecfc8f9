#!/usr/bin/env bash
# End-to-end test of `flsh simulate`: a short scene produces every output with the right
# shapes; bad scene files fail naming the key and leave the output directory empty.
# Usage: simulate_cli.sh FLSH_BINARY WORK_DIR
set -euo pipefail
flsh=$1
work=$2
rm -rf "$work" && mkdir -p "$work" && cd "$work"
here=$(pwd -P)  # what getcwd() reports: resolved paths in messages start with it
py=/usr/bin/python3
fail() { echo "FAIL: $*" >&2; exit 1; }

# 600-vertex walker, 0.3 s at h = 1/60 (18 steps), saving every 2nd step (10 frames), on the
# ground, with a ball passing its side and a static capsule.
mkdir -p data
cat > scene.json <<'EOF'
{
  "time_step": 0.016666666666666666,
  "duration": 0.3,
  "avatars": [{"name": "walker", "model": "synthetic", "vertices": 600,
               "motion": "builtin:walk", "motion_seconds": 0.5}],
  "colliders": [
    {"name": "ground", "type": "plane", "point": [0, -0.955, 0], "normal": [0, 1, 0]},
    {"name": "ball", "type": "sphere", "center": [1.0, 0.25, 0.2], "radius": 0.12,
     "velocity": [-2.5, 0, 0]},
    {"name": "bar", "type": "capsule", "a": [-1, 1.2, 0], "b": [1, 1.2, 0], "radius": 0.05}
  ],
  "outputs": {"dir": "out", "every": 2, "png_frames": 3}
}
EOF
"$flsh" simulate scene.json 2>progress.log | tee run.log
grep -q "18 steps" run.log || fail "summary should count 18 steps"
grep -q "steps/s" run.log || fail "summary should report steps/s"
grep -q "Newton iterations/step" run.log || fail "summary should report Newton iterations"
grep -q "simulation .* s, output .* s" run.log || fail "summary should split wall time"
# stderr is not a terminal here: progress lines every 10 %, ending at 100 %.
grep -q "100%" progress.log || { cat progress.log; fail "progress should reach 100%"; }

for f in out/states.npz out/animation.glb out/sheet.png; do [ -s "$f" ] || fail "missing $f"; done
[ "$(ls out/meshes/walker | wc -l)" -eq 10 ] || fail "expected 10 PLY frames"
[ -s out/meshes/walker/frame_0009.ply ] || fail "missing the last PLY frame"

$py - <<'PY'
import json, struct
import numpy as np
d = np.load("out/states.npz")
T = 10
assert d["times"].shape == (T,), d["times"].shape
assert np.allclose(d["times"], np.arange(T) * 2 / 60.0)
assert d["walker_states"].shape == (T, 144), d["walker_states"].shape
assert d["walker_vertices"].shape == (T, 600, 3), d["walker_vertices"].shape
assert d["walker_joints"].shape == (T, 24, 3)
assert d["walker_poses"].shape == (T, 72) and d["walker_trans"].shape == (T, 3)
assert d["walker_faces"].shape == (1196, 3) and d["walker_faces"].dtype == np.int64
assert d["walker_faces"].max() == 599
assert d["ball_offset"].shape == (T, 3) and d["ground_offset"].shape == (T, 3)
assert np.allclose(d["ball_offset"][:, 0], -2.5 * d["times"])
assert np.allclose(d["bar_offset"], 0)
for k in d.files:
    if d[k].dtype.kind == "f":
        assert np.isfinite(d[k]).all(), k
# The walker moves forward (+z) and stays upright, roughly on the ground.
v = d["walker_vertices"]
assert v[-1, :, 2].mean() > v[0, :, 2].mean() + 0.1, (v[0, :, 2].mean(), v[-1, :, 2].mean())
assert v[:, :, 1].min() > -1.1 and v[:, :, 1].max() < 0.9

# The glb: header, chunks, one skinned mesh per avatar, an animation over T frames.
b = open("out/animation.glb", "rb").read()
magic, version, length = struct.unpack_from("<III", b, 0)
assert magic == 0x46546C67 and version == 2 and length == len(b)
jlen, jtype = struct.unpack_from("<II", b, 12)
assert jtype == 0x4E4F534A
g = json.loads(b[20:20 + jlen])
blen, btype = struct.unpack_from("<II", b, 20 + jlen)
assert btype == 0x004E4942 and 20 + jlen + 8 + blen == len(b)
assert len(g["skins"]) == 1 and len(g["skins"][0]["joints"]) == 24
assert len(g["meshes"]) == 4  # walker, ground quad, ball, bar
pos = g["accessors"][g["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
assert pos["count"] == 600
anim = g["animations"][0]
assert len(anim["channels"]) == 24 * 2 + 2  # bones + ball and bar translations
t_acc = g["accessors"][anim["samplers"][0]["input"]]
assert t_acc["count"] == T and abs(t_acc["max"][0] - 0.3) < 1e-6
for v_ in g["bufferViews"]:
    assert v_["byteOffset"] + v_["byteLength"] <= blen
PY

"$flsh" simulate scene.json --out out2 --duration 0.1 --time-step 0.02 >run2.log 2>/dev/null
grep -q "5 steps" run2.log || { cat run2.log; fail "--duration/--time-step overrides"; }
[ "$(ls out2/meshes/walker | wc -l)" -eq 3 ] || fail "--out override: expected 3 frames (every 2 of 5 steps)"

# Two avatars, the second turned by 90° (walking towards +x) and moved; one Newton iteration
# per step, so steps are reported as not converged (a warning, not an error); npz only.
cat > two.json <<'EOF'
{
  "duration": 0.2,
  "newton": {"max_iterations": 1},
  "avatars": [{"name": "a", "vertices": 600, "motion": "builtin:walk"},
              {"name": "b", "vertices": 600, "betas": [0, 1], "motion": "builtin:walk",
               "yaw_degrees": 90, "offset": [2, 0, 0]}],
  "colliders": [{"type": "plane", "point": [0, -0.955, 0]}],
  "outputs": {"dir": "two_out", "ply": false, "gltf": false, "png": false}
}
EOF
"$flsh" simulate two.json >two.log 2>two.err || { cat two.err; fail "two avatars"; }
grep -q "steps did not converge" two.err || { cat two.err; fail "non-convergence warning"; }
[ "$(ls two_out)" = "states.npz" ] || fail "only states.npz expected in two_out, got: $(ls two_out)"
$py - <<'PY'
import numpy as np
d = np.load("two_out/states.npz")
assert d["a_vertices"].shape == (13, 600, 3) and d["b_vertices"].shape == (13, 600, 3)
assert d["plane0_offset"].shape == (13, 3)
assert np.allclose(d["b_betas"][:2], [0, 1]) and np.allclose(d["a_betas"], 0)
pa, pb = d["a_joints"][:, 0], d["b_joints"][:, 0]
assert abs(pb[0, 0] - 2.0) < 0.05 and abs(pb[0, 2]) < 0.05, pb[0]
assert pb[-1, 0] > pb[0, 0] + 0.1 and abs(pb[-1, 2] - pb[0, 2]) < 0.05, (pb[0], pb[-1])  # walks +x
assert pa[-1, 2] > pa[0, 2] + 0.1  # the unturned one walks +z
PY

# The built-in default scene (6890-vertex walker, ground, ball), a few steps only.
"$flsh" simulate --duration 0.05 --out default_out >default.log 2>/dev/null
grep -q "builtin default scene: 1 avatar(s), 2 collider(s), 3 steps" default.log || { cat default.log; fail "default scene"; }
$py -c "
import numpy as np
d = np.load('default_out/states.npz')
assert d['walker_vertices'].shape == (4, 6890, 3), d['walker_vertices'].shape
assert np.isfinite(d['walker_vertices']).all()
"

# Bad scene files: non-zero exit, a message naming the key path, nothing in the output dir.
expect_error() {  # expect_error PATTERN SCENE_TEXT
  local pattern=$1
  printf '%s' "$2" > bad.json
  rm -rf badout
  if "$flsh" simulate bad.json --out badout >/dev/null 2>err.log; then fail "expected failure for: $2"; fi
  grep -qF -- "$pattern" err.log || { cat err.log; fail "message should mention '$pattern'"; }
  if [ -e badout ] && [ -n "$(ls -A badout)" ]; then fail "output left behind for: $2"; fi
}
expect_error "bad.json: avatars[0].optoins: unknown key (known: name, model" \
  '{"avatars": [{"vertices": 600, "optoins": {}}]}'
expect_error "bad.json: malformed JSON at byte" \
  '{"avatars": [{"vertices": 600}],, }'
expect_error "avatars[0].motion: motion file not found: $here/data/missing.npz" \
  '{"avatars": [{"vertices": 600, "motion": "data/missing.npz"}]}'
expect_error "avatars[0].simulation: expected \"skeleton\", \"fem\" or \"rom\", got \"cloth\"" \
  '{"avatars": [{"vertices": 600, "simulation": "cloth"}]}'
expect_error "avatars[0].resolution: only for \"simulation\": \"fem\" or \"rom\"" \
  '{"avatars": [{"vertices": 600, "resolution": 0.5}]}'
expect_error "avatars[0].materials: material file not found: $here/data/soft.json" \
  '{"avatars": [{"vertices": 600, "simulation": "fem", "materials": "data/soft.json"}]}'
expect_error "bad.json: time_step: expected 0 < value <= 1 (s), got -0.01" \
  '{"time_step": -0.01, "avatars": [{"vertices": 600}]}'
expect_error "colliders[0].radius: expected 0 < value <= 10000 (m), got 0" \
  '{"avatars": [{"vertices": 600}], "colliders": [{"type": "sphere", "center": [0,0,0], "radius": 0}]}'
rm -rf badout
if "$flsh" simulate scene.json --duration -1 --out badout >/dev/null 2>err.log; then fail "negative --duration accepted"; fi
grep -q -- "--duration: expected 0 < value" err.log || { cat err.log; fail "--duration message"; }
[ ! -e badout ] || fail "output left behind for a bad --duration"
if "$flsh" simulate missing_scene.json --out badout >/dev/null 2>err.log; then fail "missing scene file accepted"; fi
grep -q "missing_scene.json: scene file not found" err.log || fail "missing scene file message"

echo "simulate_cli: all checks passed"
