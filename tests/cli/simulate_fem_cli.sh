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

$py - "$scale" <<'PY'
import struct, sys, zlib
import numpy as np
scale_mm = float(sys.argv[1])
d = np.load("out/states.npz")
T = 4
assert d["rigid_states"].shape == (T, 144), d["rigid_states"].shape
assert "rigid_max_displacement_mm" not in d.files
states = d["soft_states"]
assert states.shape[0] == T and states.shape[1] > 144 and (states.shape[1] - 144) % 3 == 0, states.shape
u = states[:, 144:].reshape(T, -1, 3)  # every soft-tissue node, m
m = d["soft_max_displacement_mm"]
assert m.shape == (T,) and np.isfinite(m).all() and (m >= 0).all(), m
# Surface vertices are a subset of the soft-tissue nodes: their maximum cannot exceed all nodes'.
assert (m <= 1000 * np.linalg.norm(u, axis=2).max(axis=1) + 1e-9).all(), (m, u)
assert m.max() > 0, "the soft tissue should move while walking: max displacement %s mm" % m
# The sheet shows frames 0 and 3 with one scale: their larger maximum (printed with 3 decimals).
assert abs(scale_mm - max(m[0], m[-1])) < 1e-3 + 1e-9, (scale_mm, m)
assert d["soft_vertices"].shape == (T, 600, 3) and np.isfinite(d["soft_vertices"]).all()

# Decode the 8-bit RGB PNG (non-interlaced; PNG filters undone per row).
b = open("out/sheet.png", "rb").read()
assert b[:8] == b"\x89PNG\r\n\x1a\n"
pos, idat, w = 8, b"", 0
while pos < len(b):
    n, kind = struct.unpack(">I4s", b[pos:pos + 8])
    body = b[pos + 8:pos + 8 + n]
    if kind == b"IHDR":
        w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
        assert depth == 8 and ctype == 2 and interlace == 0, (depth, ctype, interlace)
    elif kind == b"IDAT":
        idat += body
    pos += 12 + n
raw = zlib.decompress(idat)
stride = 3 * w
rows, prev = [], bytearray(stride)
for y in range(h):
    f = raw[y * (stride + 1)]
    out = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
    if f == 1:
        for x in range(3, stride): out[x] = (out[x] + out[x - 3]) & 255
    elif f == 2:
        for x in range(stride): out[x] = (out[x] + prev[x]) & 255
    elif f == 3:
        for x in range(stride):
            out[x] = (out[x] + ((out[x - 3] if x >= 3 else 0) + prev[x]) // 2) & 255
    elif f == 4:
        for x in range(stride):
            a, up, c = (out[x - 3], prev[x], prev[x - 3]) if x >= 3 else (0, prev[x], 0)
            pa, pb, pc = abs(up - c), abs(a - c), abs(a + up - 2 * c)
            out[x] = (out[x] + (a if pa <= pb and pa <= pc else (up if pb <= pc else c))) & 255
    rows.append(bytes(out))
    prev = out
img = np.frombuffer(b"".join(rows), np.uint8).astype(np.int32)
rgb = img.reshape(h, w, 3)
r, g, bl = rgb[..., 0], rgb[..., 1], rgb[..., 2]
# Skin (and the grey floor, the white background) never has blue or green above red; the
# viridis map below yellow always has: the FEM avatar is coloured, the skeleton one is not.
coloured = ((bl > r + 8) | (g > r + 8)).sum()
skin = ((r > g + 10) & (g > bl + 10) & (r < 250)).sum()
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
