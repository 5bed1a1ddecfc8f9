#!/usr/bin/env bash
# Installs dependencies, builds flsh and runs the main job (flsh simulate) on the built-in
# default scene: a synthetic avatar walking on the ground, hit by a ball.
# Usage (as root on Debian 12): bash scripts/demo.sh
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bash "$root/scripts/setup.sh"
cmake -S "$root" -B "$root/build" -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build "$root/build" -j "$(nproc 2>/dev/null || echo 2)"
"$root/build/bin/flsh" simulate --out "$root/out/simulate"
