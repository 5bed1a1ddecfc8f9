#!/usr/bin/env bash
# Installs every Debian package flsh needs. Idempotent; run as root on Debian 12.
set -euo pipefail
if [ "$(id -u)" -ne 0 ]; then
  echo "setup.sh: run as root (it calls apt-get install)" >&2
  exit 1
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update
apt-get install -y --no-install-recommends \
  build-essential cmake ninja-build pkg-config git \
  libeigen3-dev libsuitesparse-dev libopenblas-dev \
  libcgal-dev libgmp-dev libmpfr-dev libboost-dev \
  libceres-dev libgoogle-glog-dev libgflags-dev \
  libgtest-dev libgmock-dev libbenchmark-dev \
  nlohmann-json3-dev libcli11-dev libzip-dev libpng-dev libtinygltf-dev libstb-dev \
  pybind11-dev python3-dev python3-pybind11 \
  python3-numpy python3-scipy python3-pytest python3-torch python3-distributed \
  clang-14 libclang-rt-14-dev libomp-14-dev ccache
