#!/usr/bin/env bash
# Build docker/Dockerfile without a Docker engine or a registry, then run the image and check /healthz.
#
#   sudo docker/build-offline.sh            (as root; Debian/Ubuntu with apt)
#
# 1. debootstrap makes a minimal Debian bookworm root file system with python3 (3.11) from the
#    Debian mirror this machine's apt already uses;
# 2. buildah imports it as the local base image `localhost/sweepcast-base`;
# 3. buildah builds docker/Dockerfile on that base (chroot isolation, vfs storage: no daemon, no cgroups);
# 4. the image's own entrypoint runs in a buildah container (`standalone` role: local Ray, SQLite)
#    and /healthz and /readyz must answer.
set -euo pipefail
cd "$(dirname "$0")/.."
[ "$(id -u)" = 0 ] || { echo "run as root (buildah with vfs storage and debootstrap need it)" >&2; exit 2; }

work="${SWEEPCAST_IMAGE_WORK:-/var/tmp/sweepcast-image}"
bah=(buildah --storage-driver vfs)
mkdir -p "$work"

need=()
command -v buildah >/dev/null || need+=(buildah)
command -v debootstrap >/dev/null || need+=(debootstrap)
if [ ${#need[@]} -gt 0 ]; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}"
fi

mirror=$(awk '/^URIs:/ && $2 ~ /\/debian$/ {print $2; exit}' /etc/apt/sources.list.d/*.sources 2>/dev/null || true)
[ -n "$mirror" ] || mirror=$(awk '$1 == "deb" && $3 ~ /^bookworm$/ {print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)
[ -n "$mirror" ] || { echo "no Debian mirror found in apt's sources" >&2; exit 1; }

if ! "${bah[@]}" images --quiet localhost/sweepcast-base >/dev/null 2>&1; then
  echo "== debootstrap bookworm from $mirror"
  rm -rf "$work/rootfs"
  debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates bookworm "$work/rootfs" "$mirror"
  chroot "$work/rootfs" apt-get clean
  tar -C "$work/rootfs" -cf "$work/rootfs.tar" .
  ctr=$("${bah[@]}" from scratch)
  "${bah[@]}" add "$ctr" "$work/rootfs.tar" /
  "${bah[@]}" config --env LANG=C.UTF-8 "$ctr"
  "${bah[@]}" commit --quiet "$ctr" localhost/sweepcast-base
  "${bah[@]}" rm "$ctr" >/dev/null
fi

# This machine may reach the package registries through a TLS-inspecting proxy: give the base its
# certificate bundle so pip inside the build trusts what this machine's pip trusts.
ctr=$("${bah[@]}" from localhost/sweepcast-base)
"${bah[@]}" copy "$ctr" /etc/ssl/certs/ca-certificates.crt /etc/ssl/certs/ca-certificates.crt
"${bah[@]}" config --env PIP_CERT=/etc/ssl/certs/ca-certificates.crt \
  --env SSL_CERT_FILE=/etc/ssl/certs/ca-certificates.crt "$ctr"
"${bah[@]}" commit --quiet "$ctr" localhost/sweepcast-base-local
"${bah[@]}" rm "$ctr" >/dev/null

echo "== buildah bud docker/Dockerfile"
"${bah[@]}" bud --isolation chroot --build-arg BASE=localhost/sweepcast-base-local --build-arg FETCH_MODELS=0 -f docker/Dockerfile -t localhost/sweepcast:offline .

echo "== run the image and check /healthz"
ctr=$("${bah[@]}" from localhost/sweepcast:offline)
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
echo "OK: image localhost/sweepcast:offline built and served /healthz and /readyz ($(date -u +%Y-%m-%d))"
