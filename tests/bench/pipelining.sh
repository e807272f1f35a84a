#!/usr/bin/env bash
# Job wall time on a loopback farm (one prism-coordinator, one prism-worker) with the worker's
# uploads pipelined or not: cornell-two-lights at 256x256, 8 px tiles (1024 tasks of a few
# milliseconds), 8 spp, 64 bins, hero, no prepass.
#
#   tests/bench/pipelining.sh [build dir] [worker threads] [runs]     (build 1 2)
set -euo pipefail
build=${1:-build}
threads=${2:-1}
runs=${3:-2}
scene=$(cd "$(dirname "$0")/../.." && pwd)/scenes/cornell-two-lights.pbrt
export PRISM_API_TOKEN=bench PRISM_WORKER_SECRET=bench
. "$(dirname "$0")/loopback_farm.sh"
for run in $(seq "$runs"); do
  for inflight in 0 1; do
    dir=$(mktemp -d)
    start_coordinator "$build" "$dir"
    "$build/worker/prism-worker" --coordinator "$PRISM_COORDINATOR" --threads "$threads" \
      --cache-dir "$dir/cache" --uploads-in-flight "$inflight" --log-level error &
    worker=$!
    sleep 1
    start=$(date +%s.%N)
    "$build/client/prism" submit "$scene" --resolution 256x256 --spp 8 --tile 8 --bins 64 \
      --integrator hero --no-prepass --wait -o "$dir/out.exr" > "$dir/submit.log" 2>&1
    end=$(date +%s.%N)
    printf 'run %d, --uploads-in-flight %d, %d worker threads: %.2f s\n' "$run" "$inflight" \
      "$threads" "$(echo "$end - $start" | bc)"
    kill "$worker" "$coordinator"
    wait "$worker" "$coordinator" 2>/dev/null || true
    rm -rf "$dir"
  done
done
