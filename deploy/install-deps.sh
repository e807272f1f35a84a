#!/usr/bin/env bash
# Installs every Debian 12 package Prism needs to build, test and run. Idempotent: it asks apt
# only for what is missing and runs `apt-get update` at most once. Safe to rerun.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config ccache clang libclang-rt-14-dev
  libembree-dev libopenexr-dev
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libspdlog-dev libfmt-dev libtbb-dev libcli11-dev libsqlite3-dev libpng-dev
  libtinyobjloader-dev libssl-dev libcpp-httplib-dev nlohmann-json3-dev prometheus-cpp-dev
  prometheus curl slurm-wlm munge
  libgtest-dev libgmock-dev libbenchmark-dev
  gnuplot-nox fonts-dejavu-core
)

missing=()
for p in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
  [[ "$status" == "install ok installed" ]] || missing+=("$p")
done

if ((${#missing[@]} == 0)); then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo=""
if [[ $(id -u) -ne 0 ]]; then sudo="sudo"; fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
if ! $sudo apt-get install -y --no-install-recommends "${missing[@]}"; then
  $sudo apt-get update
  $sudo apt-get install -y --no-install-recommends "${missing[@]}"
fi
