#!/usr/bin/env bash
# Run the compose deployment for real with podman and check it as a user would (through the API's
# published ports only), then write the `docker` section of benchmarks/RESULTS.md.
#
#   sudo docker/verify-stack.sh          (as root, by hand, not in CI; Debian bookworm with apt; ~20 min)
#
# 1. Images (docker/images.sh): the app image (docker/Dockerfile, rebuilt unless it was built from these very
#    sources), PostgreSQL from Debian's packages and an S3 stand-in, all on one debootstrapped bookworm base.
# 2. docker/compose.yaml, changed only where this machine needs it (docker/verify/compose_for_podman.py says
#    what and why: Debian's postgres image, the S3 stand-in for MinIO, two API replicas, two Ray workers),
#    is brought up with podman-compose; secrets come from docker/.env (made from env.example with random
#    values when missing).
# 3. benchmarks/docker_stack.py submits a photo batch, a depth video and a reconstruction through the API,
#    streams the demo rig's viewer socket, kills a Ray worker container mid-job and an API container, runs
#    `down` and `up` and fetches every finished job's results again, and publishes the timings.
# With SWEEPCAST_CHAOS=1, benchmarks/docker_chaos.py then fails its containers one at a time while jobs run.
# With SWEEPCAST_SOAK_MINUTES=60, benchmarks/soak.py then runs its mixed load on the stack for that long.
# The stack is taken down at the end (volumes kept unless SWEEPCAST_KEEP_VOLUMES=0).
set -euo pipefail
cd "$(dirname "$0")/.."
[ "$(id -u)" = 0 ] || { echo "run as root (podman, buildah and debootstrap need it)" >&2; exit 2; }
source docker/images.sh
install_tools podman podman-compose buildah debootstrap runc
[ -x .venv/bin/python ] || { echo "make the project's venv first: make .venv/.sweepcast-installed" >&2; exit 2; }

if [ ! -f docker/.env ]; then
  echo "== docker/.env missing: made from docker/env.example with random secrets"
  while IFS= read -r line; do
    case "$line" in
      *=change-me*) echo "${line%%=*}=$(python3 -c 'import secrets; print(secrets.token_hex(24))')" ;;
      *) echo "$line" ;;
    esac
  done < docker/env.example > docker/.env
  chmod 600 docker/.env
fi
set -a; . docker/.env; set +a
port="${SWEEPCAST_PORT:-8000}"
project=sweepcast-verify
network="${project}_default"

sweepcast_base
# The app image is rebuilt unless its record says it was built from these very sources, without local changes.
if ! python3 -c "import json, sys; r = json.load(open(sys.argv[1])); sys.exit(r['sources'] != sys.argv[2] or r['dirty'])" \
     "$work/app-image.json" "$(image_source_tree)" 2>/dev/null || [ "$(image_source_dirty)" = true ]; then
  SWEEPCAST_REBUILD=1
fi
SWEEPCAST_REBUILD=${SWEEPCAST_REBUILD:-0} sweepcast_image
postgres_image
redis_image
s3_image

compose="$work/compose.podman.yaml"
python3 docker/verify/compose_for_podman.py docker/compose.yaml "$compose" "$port"
podman_compose=(podman-compose -p "$project" -f "$compose")

# A stack left over from an interrupted run goes first, with its volumes: every run starts empty.
"${podman_compose[@]}" down -v >/dev/null 2>&1 || true
podman rm -f "$project-s3" >/dev/null 2>&1 || true
podman network exists "$network" || podman network create "$network" >/dev/null

# The S3 stand-in, outside the compose project (see docker/verify/s3.Dockerfile), named `minio` on its network.
podman run -d --name "$project-s3" --network "$network" --network-alias minio \
  -e AWS_ACCESS_KEY_ID="$MINIO_ROOT_USER" -e AWS_SECRET_ACCESS_KEY="$MINIO_ROOT_PASSWORD" localhost/sweepcast-s3 >/dev/null
podman run --rm --network "$network" --entrypoint /opt/moto/bin/python localhost/sweepcast-s3 -c "
import time, boto3
s3 = boto3.client('s3', endpoint_url='http://minio:9000', region_name='us-east-1',
                  aws_access_key_id='$MINIO_ROOT_USER', aws_secret_access_key='$MINIO_ROOT_PASSWORD')
for _ in range(60):
    try:
        s3.create_bucket(Bucket='$S3_BUCKET'); break
    except Exception as exc:
        last = exc; time.sleep(1)
else:
    raise SystemExit(f'the S3 stand-in did not answer: {last}')
"

cleanup() {
  "${podman_compose[@]}" down $([ "${SWEEPCAST_KEEP_VOLUMES:-1}" = 1 ] || echo -v) >/dev/null 2>&1 || true
  podman rm -f "$project-s3" >/dev/null 2>&1 || true
}
trap cleanup EXIT

echo "== podman-compose up ($compose)"
.venv/bin/python -m benchmarks.docker_stack --compose "${podman_compose[*]}" --project "$project" \
  --port "$port" --image-record "$work/app-image.json" \
  --podman-version "$(podman --version), podman-compose $(dpkg-query -W -f='${Version}' podman-compose)"
echo "OK: the compose stack passed every check ($(date -u +%Y-%m-%d)); see the docker section of benchmarks/RESULTS.md"
if [ "${SWEEPCAST_CHAOS:-0}" = 1 ]; then  # then its containers failed one at a time (benchmarks/docker_chaos.py)
  echo "== chaos: the stack's containers failed while jobs run"
  .venv/bin/python -m benchmarks.docker_chaos --compose "${podman_compose[*]}" --project "$project" --port "$port"
fi
if [ -n "${SWEEPCAST_SOAK_MINUTES:-}" ]; then  # then the hour of mixed load on the same stack (benchmarks/soak.py)
  echo "== soak: ${SWEEPCAST_SOAK_MINUTES} minutes of mixed load"
  .venv/bin/python -m benchmarks.soak --minutes "$SWEEPCAST_SOAK_MINUTES" --name soak_compose \
    --base "http://127.0.0.1:$port" --base "http://127.0.0.1:$((port + 1))" --podman-project "$project"
fi
