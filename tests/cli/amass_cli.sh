#!/usr/bin/env bash
# AMASS clips as users have them (issue 27): a z-up clip with SMPL-H poses, 16 betas and no
# `up` key is posed upright by `flsh pose`; read as y up it lies down and flsh warns; the
# example scene examples/scenes/amass_clip.json (skeleton, FEM and ROM tracking the clip on
# "ground": "auto") runs on a small body with every avatar's feet on the ground.
# Usage: amass_cli.sh FLSH_BINARY WORK_DIR
set -euo pipefail
flsh=$1
work=$2
root=$(cd "$(dirname "$0")/../.." && pwd)
rm -rf "$work" && mkdir -p "$work" && cd "$work"
py=/usr/bin/python3
fail() { echo "FAIL: $*" >&2; exit 1; }

"$flsh" synth-body --out body.npz --vertices 600 >/dev/null
"$flsh" motion --name walk --seconds 1 --fps 30 --up z --out walk_z.npz | grep -qF "z up" ||
  fail "flsh motion --up z should say the frame"
# As AMASS stores it: no `up` key, 156 pose values, 16 betas, 120 Hz-style keys, a gender, and
# the clip's floor 1.5 m off the origin.
$py - <<'PY'
import numpy as np
src = np.load("walk_z.npz")
assert str(src["up"]) == "z"
T = src["poses"].shape[0]
poses = np.zeros((T, 156))
poses[:, :66] = src["poses"][:, :66]
poses[:, 66:] = 0.1
trans = src["trans"] + np.array([0.3, 1.5, -0.4])
np.savez("clip.npz", poses=poses, trans=trans, betas=np.zeros(16), mocap_framerate=np.array(30.0),
         gender=np.array("female"), dmpls=np.zeros((T, 8)))
PY

# ---- flsh pose: upright by default (AMASS is z up), lying with --up y ----
"$flsh" pose --model body.npz --motion clip.npz --out upright.npz 2>err.log >/dev/null
grep -q "not upright" err.log && { cat err.log; fail "a z-up clip read as z up is upright"; }
"$flsh" pose --model body.npz --motion clip.npz --up y --out lying.npz 2>err.log >/dev/null
grep -qF "the body is not upright at frame 0" err.log || { cat err.log; fail "no upright warning"; }
grep -qF -- "--up z for flsh pose" err.log || { cat err.log; fail "the warning should say how"; }
$py - <<'PY'
import numpy as np
for name, upright in (("upright.npz", True), ("lying.npz", False)):
    joints = np.load(name)["joints"]  # (T, 24, 3)
    rise = joints[0, 15, 1] - joints[0, 0, 1]  # head above the pelvis, m
    assert (rise > 0.3) == upright, (name, rise)
PY

# ---- the example scene, small: each model tracks the clip standing on the auto ground ----
cp clip.npz amass_clip.npz
$py - "$root/examples/scenes/amass_clip.json" <<'PY'
import json, sys
scene = json.load(open(sys.argv[1]))
assert scene["ground"] == "auto"
scene["duration"] = 0.3
scene["outputs"] = {"dir": "out", "ply": False, "png": False, "gltf": False}
scene["cache_dir"] = "cache"
for avatar in scene["avatars"]:
    avatar["vertices"] = 600
    if avatar.get("simulation") in ("fem", "rom"):
        avatar["resolution"] = 0.3
    if avatar.get("simulation") == "rom":
        avatar.update(handles=12, elastic_cubature=40, inertial_cubature=40)
json.dump(scene, open("scene.json", "w"), indent=1)
PY
"$flsh" simulate scene.json >out.log 2>err.log || { cat err.log; fail "simulate failed"; }
grep -qF "ground: auto, plane at y = " err.log || { cat err.log; fail "no ground report"; }
grep -q "warning: avatar" err.log && { cat err.log; fail "no avatar should start off the ground"; }
grep -qE "3 avatar\(s\), 1 collider\(s\) \(ground at y = -?[0-9.]+ m, auto\)" out.log ||
  { cat out.log; fail "the summary line should report the auto ground"; }
contacts=$(grep -oE "max [0-9]+ contacts" out.log | grep -oE "[0-9]+")
[ "$contacts" -gt 0 ] || { cat out.log; fail "the feet should touch the ground"; }
$py - <<'PY'
import numpy as np
d = np.load("out/states.npz")
for name in ("skeleton", "fem", "rom"):
    key = [k for k in d.files if k.startswith(name) and k.endswith("vertices")]
    assert key, (name, d.files)
    v = d[key[0]][-1].reshape(-1, 3)
    height = v[:, 1].max() - v[:, 1].min()
    assert height > 1.3, (name, height)  # standing, not lying
PY
echo "amass_cli: ok"
