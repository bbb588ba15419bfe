#!/usr/bin/env bash
# `ray job submit` commands for a running vid2sim cluster (launcher or KubeRay).
# Needs the cluster's token: RAY_AUTH_MODE=token and RAY_AUTH_TOKEN (or ~/.ray/auth_token).
# RAY_ADDRESS: the dashboard, e.g. http://127.0.0.1:8265 after `ray dashboard cluster/ray-cluster.aws.yaml`
# or `kubectl port-forward svc/vid2sim-head-svc 8265`.
set -euo pipefail
export RAY_AUTH_MODE=token
: "${RAY_ADDRESS:=http://127.0.0.1:8265}"
DATA="${VID2SIM_DATA:-s3://vid2sim-data}"

case "${1:-}" in
  ingest)  # --working-dir ships manifests/ (and the code) to the cluster
    ray job submit --address "$RAY_ADDRESS" --entrypoint-num-cpus 0 --working-dir . -- \
      vid2sim ingest "${MANIFEST:-manifests/cluster_s3.yaml}" --registry "$DATA/registry" \
      --workdir "$DATA/work" --preset fast --ray-address auto --json ;;
  train)
    ray job submit --address "$RAY_ADDRESS" --entrypoint-num-cpus 0 -- \
      vid2sim train --registry "$DATA/registry" --run "$DATA/runs/train-1" --actors 8 --envs 16 \
      --ray-address auto ;;
  study)
    ray job submit --address "$RAY_ADDRESS" --entrypoint-num-cpus 0 -- \
      vid2sim study --registry "$DATA/registry" --out "$DATA/runs/study-1" --counts 1,5,15,30 --seeds 3 \
      --ray-address auto ;;
  *) echo "usage: $0 ingest|train|study" >&2; exit 2 ;;
esac
