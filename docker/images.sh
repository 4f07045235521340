# Offline image builds, sourced by build-offline.sh and verify-stack.sh (as root; Debian with apt).
# No registry is reachable from our machines, so every base is a debootstrapped Debian bookworm root
# file system imported into buildah; podman and buildah share one store (the configuration below).
#
#   sweepcast_base      localhost/sweepcast-base(-local): bookworm minbase + python3 (+ this machine's CA bundle)
#   sweepcast_image     localhost/sweepcast:latest        docker/Dockerfile (api, ray-head, ray-worker roles)
#   postgres_image      localhost/sweepcast-postgres      Debian's postgresql on the same base
#   s3_image            localhost/sweepcast-s3            moto's S3 server on the same base (stands in for MinIO)
#   redis_image         localhost/sweepcast-redis         Debian's redis-server on the same base (Ray's GCS store)
# Each is built only when missing (SWEEPCAST_REBUILD=1 rebuilds the app image).

work="${SWEEPCAST_IMAGE_WORK:-/var/tmp/sweepcast-image}"
mkdir -p "$work"
# One storage driver for buildah and podman: overlay where the kernel mounts it on this file system (what Docker
# uses: a container starts on the image's layers), else vfs (no overlay or fuse needed, but every container and
# build step copies the whole image first: 9-10 s per app container here, one after another under podman-compose,
# 43 of the 61 s from `up` to ready on 2026-11-29). SWEEPCAST_STORAGE_DRIVER chooses. Each driver has its own store.
# runc (crun fails on hybrid cgroups) and explicit ulimits (the defaults podman derives from this machine's limits
# fail to apply).
overlay_mounts() {
  local d rc=1
  grep -qw overlay /proc/filesystems || return 1
  d=$(mktemp -d "$work/overlay-probe.XXXXXX")
  mkdir "$d/lower" "$d/upper" "$d/work" "$d/merged"
  if mount -t overlay overlay -o "lowerdir=$d/lower,upperdir=$d/upper,workdir=$d/work" "$d/merged" 2>/dev/null; then
    umount "$d/merged"; rc=0
  fi
  rm -rf "$d"
  return $rc
}
storage_driver="${SWEEPCAST_STORAGE_DRIVER:-$(overlay_mounts && echo overlay || echo vfs)}"
store=storage
[ "$storage_driver" = vfs ] || store="storage-$storage_driver"
cat > "$work/storage.conf" <<CONF
[storage]
driver = "$storage_driver"
runroot = "/run/containers/$store"
graphroot = "/var/lib/containers/$store"
CONF
cat > "$work/containers.conf" <<'CONF'
[containers]
default_ulimits = ["nofile=16384:16384", "nproc=8192:8192"]
[engine]
runtime = "runc"
CONF
export CONTAINERS_STORAGE_CONF="$work/storage.conf" CONTAINERS_CONF="$work/containers.conf"
bah=(buildah --storage-driver "$storage_driver")
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
    # The image this build replaced is left untagged; ~2 GB each, so repeated runs filled /var/tmp (2026-11-29).
    "${bah[@]}" rmi --prune >/dev/null || true
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
