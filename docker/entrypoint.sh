#!/bin/sh
# Roles: api (serve, joining the Ray cluster as a node without CPUs meanwhile), ray-head, ray-worker,
# standalone (embedded local Ray, SQLite, /data), or any other command.
set -eu
role="${1:-api}"
# the YuNet model the image was built with, unless the operator names another
yunet=/opt/sweepcast/models/face_detection_yunet_2023mar.onnx
if [ -z "${SWEEPCAST_ORIENTATION_YUNET_MODEL:-}" ] && [ -f "$yunet" ]; then
  export SWEEPCAST_ORIENTATION_YUNET_MODEL="$yunet"
fi
# The kernels compiled into the image (SWEEPCAST_PREBUILT_KERNELS, for x86-64-v3): copied into /data's cache and
# numba's CPU target set to theirs, for every process of this container (Ray's included); on a CPU without that
# baseline, nothing set: they compile for this CPU into /data instead (the log says why, and /readyz). `sweepcast
# serve` and `sweepcast worker` do it themselves before they start Ray's processes; the head's `ray start` is given
# it here (a Python start of its own: a third of a second before the API's could begin).
case "$role" in ray-head) eval "$(sweepcast kernel-env)" ;; esac
case "$role" in
  api)
    # with a cluster: the service joins it as a node without CPUs while it imports itself (ray_join_node), and
    # exits (code 3) to be restarted when the head cannot be reached
    if [ -n "${SWEEPCAST_RAY_ADDRESS:-}" ]; then
      export SWEEPCAST_RAY_JOIN_NODE=true
    fi
    exec sweepcast serve
    ;;
  standalone)
    exec sweepcast serve
    ;;
  ray-head)
    # its state in Redis (RAY_REDIS_ADDRESS): a GCS started before Redis answers, or while it loads its data, fails;
    # and it is given Redis's IP, not its name: the GCS looks the name up once, and a lookup that a container
    # network's DNS drops while the stack starts blocked it 40 s and crashed it (docs/deploy.md). A Redis that
    # comes back elsewhere ends the GCS, and this container's restart looks the name up again.
    if [ -n "${RAY_REDIS_ADDRESS:-}" ]; then
      if reached="$(sweepcast wait-for --redis "$RAY_REDIS_ADDRESS" --timeout 120 --print-reached)"; then
        export RAY_REDIS_ADDRESS="$reached"
      fi
    fi
    exec ray start --head --block --port=6379 --num-cpus="${RAY_HEAD_CPUS:-0}" \
      --include-dashboard=false --disable-usage-stats
    ;;
  ray-worker)
    exec sweepcast worker --address="${SWEEPCAST_RAY_ADDRESS:?set SWEEPCAST_RAY_ADDRESS=ray-head:6379}" \
      ${RAY_WORKER_CPUS:+--num-cpus "$RAY_WORKER_CPUS"} ${RAY_WORKER_RESOURCES:+--resources "$RAY_WORKER_RESOURCES"}
    ;;
  *)
    exec "$@"
    ;;
esac
