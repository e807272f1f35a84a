#!/usr/bin/env bash
# Installs every Debian 12 package Prism needs to build, test and run, and the npm packages of
# the Kubernetes manifest check (deploy/k8s/test) and the dashboard's browser test
# (tests/browser), each pinned by its package-lock.json. Idempotent:
# it asks apt only for what is missing, runs `apt-get update` at most once, and runs `npm ci`
# only when the lock file changed. Safe to rerun. PRISM_SKIP_TEST_TOOLS=1 (the container build)
# leaves out what only the tests use.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config ccache clang libclang-rt-14-dev
  libembree-dev libopenexr-dev
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libspdlog-dev libfmt-dev libtbb-dev libcli11-dev libsqlite3-dev libpng-dev
  libtinyobjloader-dev libssl-dev libcpp-httplib-dev nlohmann-json3-dev prometheus-cpp-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  gnuplot-nox fonts-dejavu-core
)
# What the tests start: a real Prometheus and curl (the HTTP API), a single-host Slurm, the
# Kubernetes manifest check (kubectl's kustomize, Python's YAML reader, Node.js) and headless
# Chromium for the dashboard.
test_packages=(prometheus curl slurm-wlm munge python3-yaml chromium)
# Installed only when the command is missing, so a kubectl or Node.js the machine already has
# from elsewhere is kept (Debian's packages would conflict with them).
declare -A test_commands=([kubectl]=kubernetes-client [node]=nodejs [npm]=npm)

here=$(cd "$(dirname "$0")" && pwd)
with_tests=1
[[ "${PRISM_SKIP_TEST_TOOLS:-0}" == 1 ]] && with_tests=0
if ((with_tests)); then
  packages+=("${test_packages[@]}")
  for command in "${!test_commands[@]}"; do
    command -v "$command" > /dev/null || packages+=("${test_commands[$command]}")
  done
fi

missing=()
for p in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
  [[ "$status" == "install ok installed" ]] || missing+=("$p")
done

sudo=""
if [[ $(id -u) -ne 0 ]]; then sudo="sudo"; fi
if ((${#missing[@]} == 0)); then
  echo "install-deps: all ${#packages[@]} packages present"
else
  echo "install-deps: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  if ! $sudo apt-get install -y --no-install-recommends "${missing[@]}"; then
    $sudo apt-get update
    $sudo apt-get install -y --no-install-recommends "${missing[@]}"
  fi
fi

if ((with_tests)); then
  for dir in "$here/k8s/test" "$here/../tests/browser"; do
    stamp=$dir/node_modules/.package-lock.json
    if [[ ! -f "$stamp" || "$dir/package-lock.json" -nt "$stamp" ]]; then
      echo "install-deps: npm ci in $(realpath --relative-to="$here/.." "$dir")"
      (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error)
    fi
  done
fi
