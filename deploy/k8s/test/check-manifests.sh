#!/bin/bash
# Renders each overlay of deploy/k8s with `kubectl kustomize` (offline) and checks the result
# against the Kubernetes schemas (check-manifests.cjs). ctest runs it (label k8s); the npm
# packages come from deploy/install-deps.sh (`npm ci` here, pinned by package-lock.json).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
[[ -d "$here/node_modules/kubernetes-models" ]] ||
  { echo "run deploy/install-deps.sh first (npm ci in $here)" >&2; exit 1; }
for overlay in "$here"/../overlays/*/; do
  echo "== $(basename "$overlay")"
  kubectl kustomize "$overlay" 2> >(grep -v '^# Warning:' >&2) |
    python3 -c 'import json, sys, yaml; print(json.dumps([d for d in yaml.safe_load_all(sys.stdin) if d]))' |
    (cd "$here" && node check-manifests.cjs)
done
