# Offline image builds, sourced by build-offline.sh and verify-stack.sh (as root; Debian with apt).
# No registry is reachable from our machines, so every base is a debootstrapped Debian bookworm root
# file system imported into buildah; podman and buildah share one vfs store (the configuration below).
#
#   sweepcast_base      localhost/sweepcast-base(-local): bookworm minbase + python3 (+ this machine's CA bundle)
#   sweepcast_image     localhost/sweepcast:latest        docker/Dockerfile (api, ray-head, ray-worker roles)
#   postgres_image      localhost/sweepcast-postgres      Debian's postgresql on the same base
#   s3_image            localhost/sweepcast-s3            moto's S3 server on the same base (stands in for MinIO)
#   redis_image         localhost/sweepcast-redis         Debian's redis-server on the same base (Ray's GCS store)
# Each is built only when missing (SWEEPCAST_REBUILD=1 rebuilds the app image).

work="${SWEEPCAST_IMAGE_WORK:-/var/tmp/sweepcast-image}"
mkdir -p "$work"
# One storage driver for buildah and podman (vfs: no overlay or fuse needed), runc (crun fails on hybrid
# cgroups) and explicit ulimits (the defaults podman derives from this machine's limits fail to apply).
cat > "$work/storage.conf" <<'CONF'
[storage]
driver = "vfs"
runroot = "/run/containers/storage"
graphroot = "/var/lib/containers/storage"
CONF
cat > "$work/containers.conf" <<'CONF'
[containers]
default_ulimits = ["nofile=16384:16384", "nproc=8192:8192"]
[engine]
runtime = "runc"
CONF
export CONTAINERS_STORAGE_CONF="$work/storage.conf" CONTAINERS_CONF="$work/containers.conf"
bah=(buildah --storage-driver vfs)
# What the app image is built from (the package metadata's README aside): its git tree, and whether it has local changes.
image_sources=(app workers docker/Dockerfile docker/entrypoint.sh pyproject.toml)
image_source_tree() { git ls-tree -r HEAD -- "${image_sources[@]}" | sha256sum | cut -c1-16; }
image_source_dirty() { git diff --quiet HEAD -- "${image_sources[@]}" && echo false || echo true; }

install_tools() {
  local need=() tool
  for tool in "$@"; do command -v "$tool" >/dev/null || need+=("$tool"); done
  if [ ${#need[@]} -gt 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}"
  fi
}

have_image() { "${bah[@]}" inspect --type image "$1" >/dev/null 2>&1; }

sweepcast_base() {
  local mirror ctr
  mirror=$(awk '/^URIs:/ && $2 ~ /\/debian$/ {print $2; exit}' /etc/apt/sources.list.d/*.sources 2>/dev/null || true)
  [ -n "$mirror" ] || mirror=$(awk '$1 == "deb" && $3 ~ /^bookworm$/ {print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)
  [ -n "$mirror" ] || { echo "no Debian mirror found in apt's sources" >&2; return 1; }
  if ! have_image localhost/sweepcast-base; then
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
    rm -rf "$work/rootfs" "$work/rootfs.tar"
  fi
  # This machine may reach the package registries through a TLS-inspecting proxy: give the base its
  # certificate bundle so pip inside the build trusts what this machine's pip trusts.
  if ! have_image localhost/sweepcast-base-local; then
    ctr=$("${bah[@]}" from localhost/sweepcast-base)
    "${bah[@]}" copy "$ctr" /etc/ssl/certs/ca-certificates.crt /etc/ssl/certs/ca-certificates.crt
    "${bah[@]}" config --env PIP_CERT=/etc/ssl/certs/ca-certificates.crt \
      --env SSL_CERT_FILE=/etc/ssl/certs/ca-certificates.crt "$ctr"
    "${bah[@]}" commit --quiet "$ctr" localhost/sweepcast-base-local
    "${bah[@]}" rm "$ctr" >/dev/null
  fi
}

sweepcast_image() {
  # Its build time and source commit are kept next to the store, so a run that reuses the image reports both.
  if [ "${SWEEPCAST_REBUILD:-0}" = 1 ] || ! have_image localhost/sweepcast:latest; then
    echo "== buildah bud docker/Dockerfile"
    local start; start=$(date +%s)
    "${bah[@]}" bud --isolation chroot --format docker --build-arg BASE=localhost/sweepcast-base-local \
      --build-arg FETCH_MODELS=0 -f docker/Dockerfile -t localhost/sweepcast:latest .
    printf '{"seconds": %s, "built_at": "%s", "commit": "%s", "sources": "%s", "dirty": %s}\n' \
      "$(( $(date +%s) - start ))" "$(date -u +%Y-%m-%dT%H:%M:%SZ)" "$(git rev-parse HEAD)" "$(image_source_tree)" \
      "$(image_source_dirty)" > "$work/app-image.json"
  fi
}

postgres_image() {
  have_image localhost/sweepcast-postgres || "${bah[@]}" bud --isolation chroot \
    --build-arg BASE=localhost/sweepcast-base-local -f docker/verify/postgres.Dockerfile -t localhost/sweepcast-postgres docker/verify
}

redis_image() {
  have_image localhost/sweepcast-redis || "${bah[@]}" bud --isolation chroot \
    --build-arg BASE=localhost/sweepcast-base-local -f docker/verify/redis.Dockerfile -t localhost/sweepcast-redis docker/verify
}

s3_image() {
  have_image localhost/sweepcast-s3 || "${bah[@]}" bud --isolation chroot \
    --build-arg BASE=localhost/sweepcast-base-local -f docker/verify/s3.Dockerfile -t localhost/sweepcast-s3 docker/verify
}
