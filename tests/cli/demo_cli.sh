#!/usr/bin/env bash
# `flsh demo` on a small body: meshes, npz files and a PNG picture are written.
set -euo pipefail
flsh=$1
work=$2
rm -rf "$work" && mkdir -p "$work"
"$flsh" demo --out "$work/demo" --vertices 600 --seconds 0.3 | tee "$work/demo.log"
test -s "$work/demo/sheet.png"
test "$(ls "$work/demo/meshes" | wc -l)" -eq 10
head -c 8 "$work/demo/sheet.png" | od -c | grep -q "P   N   G" 
/usr/bin/python3 -c "
import numpy as np
d = np.load('$work/demo/posed.npz'); assert d['vertices'].shape == (10, 600, 3)
"
echo "demo_cli: all checks passed"
