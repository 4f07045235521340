#!/usr/bin/env bash
# A wheel that carries its kernels and the demo recording: `make wheel` (dist/sweepcast-*.whl).
#
# `pip install` of it and `sweepcast serve` on a new machine and data folder compile nothing and render nothing before
# the first viewer frame, photo or reconstruction: every engine's kernels are compiled here for the portable CPU target
# x86-64-v3 (what they lose against the host's own: benchmarks/RESULTS.md, kernel_target) into
# workers/_prebuilt/kernels, and the demo rig's recording is rendered into workers/_prebuilt/demo; the service uses both
# when the CPU, the sources, numba and Python match them (app.settings.Settings.resolved_prebuilt_kernels), and
# compiles in the background, saying why, when they do not. All of it happens in a copy of the sources (the files git
# would commit), so this checkout keeps compiling for its own CPU.
#
# usage: packaging/build-wheel.sh [OUT_DIR]   (default dist; PYTHON: the environment to compile with, .venv/bin/python)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out=$(mkdir -p "${1:-$root/dist}" && cd "${1:-$root/dist}" && pwd)
python=${PYTHON:-$root/.venv/bin/python}
case $python in /*) ;; */*) python=$PWD/$python ;; esac  # a relative path: from where we were called
target=x86-64-v3

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
src=$work/sweepcast
mkdir -p "$src"
cd "$root"
# the files a commit would hold (tracked and new, not ignored), as they are now
git ls-files -z --cached --others --exclude-standard -- pyproject.toml README.md app workers \
  | while IFS= read -r -d '' f; do [ -f "$f" ] && printf '%s\0' "$f"; done \
  | tar --null -T - -cf - | tar -xf - -C "$src"

prebuilt=$src/workers/_prebuilt
imported=$(cd "$work" && PYTHONPATH="$src" "$python" -c 'import workers; print(workers.__file__)')
[ "$imported" = "$src/workers/__init__.py" ] || { echo "build-wheel: $python imports workers from $imported, not the copy" >&2; exit 1; }
echo "build-wheel: compiling every engine's kernels for $target and rendering the demo recording (about 2 minutes)" >&2
(cd "$work" && env PYTHONPATH="$src" NUMBA_CACHE_DIR="$prebuilt/kernels" SWEEPCAST_DEMO_CACHE_DIR="$prebuilt/demo" \
   SWEEPCAST_DATA_DIR="$work/data" RAY_USAGE_STATS_ENABLED=0 \
   "$python" -m app warmup --target "$target")
find "$prebuilt" -name '*.part' -delete
stamp=$(cat "$prebuilt/kernels/warmed.json")
case $stamp in *"\"cpu_name\": \"$target\""*) ;; *) echo "build-wheel: the kernels are not stamped for $target: $stamp" >&2; exit 1;; esac
"$python" -m pip wheel --quiet --no-deps --wheel-dir "$out" "$src"
ls -l "$out"/sweepcast-*.whl
