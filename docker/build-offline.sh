#!/usr/bin/env bash
# Build docker/Dockerfile without a Docker engine or a registry, then run the image and check /healthz.
#
#   sudo docker/build-offline.sh            (as root; Debian/Ubuntu with apt)
#
# (docker/images.sh does 1-3)
# 1. debootstrap makes a minimal Debian bookworm root file system with python3 (3.11) from the
#    Debian mirror this machine's apt already uses;
# 2. buildah imports it as the local base image `localhost/sweepcast-base`;
# 3. buildah builds docker/Dockerfile on that base (chroot isolation, overlay or vfs storage: no daemon, no cgroups);
# 4. the image's own entrypoint runs in a buildah container (`standalone` role: local Ray, SQLite)
#    and /healthz and /readyz must answer.
set -euo pipefail
cd "$(dirname "$0")/.."
[ "$(id -u)" = 0 ] || { echo "run as root (buildah and debootstrap need it)" >&2; exit 2; }

source docker/images.sh
install_tools buildah debootstrap
sweepcast_base
SWEEPCAST_REBUILD=1 sweepcast_image

echo "== run the image and check /healthz"
ctr=$("${bah[@]}" from localhost/sweepcast:latest)
trap '"${bah[@]}" rm "$ctr" >/dev/null 2>&1 || true' EXIT
port=${SWEEPCAST_IMAGE_TEST_PORT:-18080}
data="/tmp/sweepcast-offline-check-$$"
"${bah[@]}" run --isolation chroot --network host --user sweepcast \
  --env SWEEPCAST_HOST=127.0.0.1 --env SWEEPCAST_PORT="$port" --env SWEEPCAST_DATA_DIR="$data" \
  "$ctr" -- sweepcast-entrypoint standalone > "$work/run.log" 2>&1 &
runner=$!
ok=""
for _ in $(seq 1 120); do
  if python3 -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:$port/readyz', timeout=2)" 2>/dev/null; then
    ok=yes; break
  fi
  sleep 1
done
python3 -c "import urllib.request; print(urllib.request.urlopen('http://127.0.0.1:$port/healthz', timeout=2).read().decode())" || true
pkill -f "$data" || true  # the served process and its Ray, by their unique data folder
kill "$runner" 2>/dev/null || true
wait "$runner" 2>/dev/null || true
if [ -z "$ok" ]; then
  echo "the image did not become ready; its log:" >&2; tail -50 "$work/run.log" >&2; exit 1
fi
echo "OK: image localhost/sweepcast:latest built and served /healthz and /readyz ($(date -u +%Y-%m-%d))"
