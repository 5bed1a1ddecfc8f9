#!/usr/bin/env bash
# Installs the build into a temporary prefix and uses it from outside the tree: a C++ project
# with find_package(flsh CONFIG) (flsh::flsh and flsh::ceres), the installed `flsh` program, and
# `import flsh, flsh.torch` from the installed Python package.
# Usage: install_test.sh BUILD_DIR WORK_DIR [PYTHON]
set -euo pipefail
build=$1
work=$2
python=${3:-/usr/bin/python3}
here=$(cd "$(dirname "$0")" && pwd)
rm -rf "$work"
mkdir -p "$work"
prefix=$work/prefix

cmake --install "$build" --prefix "$prefix" > "$work/install.log"
for f in bin/flsh include/flsh/body/body_forward.h lib/cmake/flsh/flshConfig.cmake \
  lib/cmake/flsh/flshTargets.cmake; do
  [ -e "$prefix/$f" ] || { echo "install_test: $prefix/$f was not installed" >&2; exit 1; }
done
# Nothing of the build or source tree may be needed by what was installed.
if grep -rq "$build\|$(cd "$here/../.." && pwd)/include" "$prefix/lib/cmake/flsh/"; then
  echo "install_test: the installed CMake package refers to the build or source tree" >&2
  exit 1
fi

# C++: configure, build and run the outside project against the prefix.
cmake -S "$here/consumer" -B "$work/consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$prefix" > "$work/consumer.log"
cmake --build "$work/consumer" >> "$work/consumer.log"
"$work/consumer/pose_synthetic"
if [ -x "$work/consumer/shape_prior" ]; then "$work/consumer/shape_prior"; fi

# The installed program.
"$prefix/bin/flsh" --help > /dev/null

# Python: the package from the prefix, imported from another folder.
site=$(find "$prefix/lib" -maxdepth 3 -type d -path "*python3*/*-packages" | head -n 1)
if [ -n "$site" ] && [ -d "$site/flsh" ]; then
  (cd "$work" && PYTHONPATH="$site" "$python" -c "
import flsh, flsh.torch, sys
assert flsh.__file__.startswith('$site'), flsh.__file__
body = flsh.make_synthetic_body(vertices=300)
print('python: flsh from', flsh.__file__, 'vertices', body.num_vertices)
")
else
  echo "install_test: no Python package under $prefix/lib (built without FLSH_PYTHON?)"
fi
echo "install_test: passed"
