#!/usr/bin/env bash
# One big job rendered twice, as issue 18 asks: by `prism render` (embedded) and by a loopback
# farm of one prism-coordinator and two prism-worker processes (--threads 1 each), with
# scenes/prism.pbrt, hero, no prepass. Prints each side's wall time and peak RSS (the
# coordinator's VmHWM for the farm), the farm data directory's largest disk use (allocated
# blocks, sampled every second) and whether the two spectral EXRs are the same bytes.
#
#   tests/bench/big_farm_job.sh [build dir] [resolution] [bins] [spp] [work dir]
#   tests/bench/big_farm_job.sh build 7680x4320 64 1 /var/tmp/big      (the issue's 8K job)
set -euo pipefail
build=$(cd "${1:-build}" && pwd)
resolution=${2:-1024x1024}
bins=${3:-64}
spp=${4:-1}
work=${5:-$(mktemp -d)}
scenes=$(cd "$(dirname "$0")/../.." && pwd)/scenes
options=(--resolution "$resolution" --bins "$bins" --spp "$spp" --integrator hero --no-prepass)
mkdir -p "$work"
export PRISM_API_TOKEN=bench PRISM_WORKER_SECRET=bench
. "$(dirname "$0")/loopback_farm.sh"

echo "== prism render $resolution, $bins bins, $spp spp"
start=$(date +%s.%N)
# From the scene's folder: the EXR records the scene's path as given, which is what the farm
# records (the path inside the bundle), so whole files can be compared.
(cd "$scenes" && "$build/client/prism" render prism.pbrt "${options[@]}" -o "$work/local.exr") \
  > "$work/render.log" 2>&1
end=$(date +%s.%N)
tail -n 2 "$work/render.log"
printf 'prism render: %.1f s\n' "$(echo "$end - $start" | bc)"

echo "== farm: one coordinator, two workers of one thread"
rm -rf "$work/data"
start_coordinator "$build" "$work"
workers=()
for i in 1 2; do
  "$build/worker/prism-worker" --coordinator "$PRISM_COORDINATOR" --threads 1 \
    --cache-dir "$work/cache$i" --log-level error &
  workers+=($!)
done
peak_disk=0
peak_rss=0
(
  while kill -0 "$coordinator" 2>/dev/null; do
    disk=$(du -s --block-size=1 "$work/data" 2>/dev/null | awk '{print $1}')
    rss=$(awk '/VmRSS/ {print $2}' "/proc/$coordinator/status" 2>/dev/null || echo 0)
    echo "$disk ${rss:-0}"
    sleep 1
  done
) > "$work/samples.txt" &
sampler=$!
start=$(date +%s.%N)
"$build/client/prism" submit "$scenes/prism.pbrt" "${options[@]}" --wait -o "$work/farm.exr" \
  > "$work/submit.log" 2>&1
end=$(date +%s.%N)
hwm=$(awk '/VmHWM/ {print $2}' "/proc/$coordinator/status")
kill "${workers[@]}" "$coordinator"
wait "${workers[@]}" "$coordinator" 2>/dev/null || true
kill "$sampler" 2>/dev/null || true
wait "$sampler" 2>/dev/null || true
read -r peak_disk peak_rss < <(awk 'BEGIN {d = 0; r = 0} {if ($1 > d) d = $1; if ($2 > r) r = $2}
  END {print d, r}' "$work/samples.txt")
printf 'farm (submit to outputs fetched): %.1f s\n' "$(echo "$end - $start" | bc)"
printf 'coordinator peak RSS (VmHWM): %.0f MiB\n' "$(echo "$hwm / 1024" | bc -l)"
printf 'data directory, largest disk use sampled: %.2f GB\n' "$(echo "$peak_disk / 1000000000" | bc -l)"
for f in local.exr local.rgb.exr local.png; do
  g=${f/local/farm}
  if cmp -s "$work/$f" "$work/$g"; then echo "$f and $g: identical bytes"; else
    echo "$f and $g: DIFFERENT"; fi
done
