#!/bin/bash
# Builds deploy/container/Dockerfile where a container engine runs (docker or podman with a
# reachable daemon), then checks the image starts its binaries. Where none runs it says so and
# exits 77, which ctest reports as skipped (label container).
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
engine=""
for candidate in docker podman; do
  if command -v "$candidate" > /dev/null && "$candidate" info > /dev/null 2>&1; then
    engine=$candidate
    break
  fi
done
if [[ -z "$engine" ]]; then
  echo "no container engine runs on this machine (docker/podman info failed): image not built"
  exit 77
fi
"$engine" build -f "$root/deploy/container/Dockerfile" -t prism:test "$root"
for binary in prism prism-coordinator prism-worker; do
  "$engine" run --rm prism:test "$binary" --help > /dev/null
done
echo "built prism:test with $engine; its binaries start"
