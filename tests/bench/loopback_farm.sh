# Sourced by the bench scripts that run a loopback farm. start_coordinator BUILD DIR starts a
# prism-coordinator on 127.0.0.1 with its data in DIR/data and its log in DIR/coordinator.log,
# waits until it listens, and sets $coordinator (its pid) and exports $PRISM_COORDINATOR.
start_coordinator() {
  local build=$1 dir=$2 port
  "$build/coordinator/prism-coordinator" --listen 127.0.0.1:0 --data-dir "$dir/data" \
    > "$dir/coordinator.log" 2>&1 &
  coordinator=$!
  for _ in $(seq 100); do grep -q "listening on port" "$dir/coordinator.log" && break; sleep 0.1; done
  port=$(grep -o "listening on port [0-9]*" "$dir/coordinator.log" | awk '{print $4}')
  export PRISM_COORDINATOR=127.0.0.1:$port
}
