#!/usr/bin/env bash
# Packs, here, what `bash ci/gpu_check.sh` needs on a bare device machine, into folders of
# this checkout that git ignores and the device tool carries:
#   .whl/      this venv's versions of the packages the device image lacks, as wheels for its
#              Python (3.12; GPU_PYTHON sets another)
#   .gl/       the Vulkan loader's .deb files
#   .gpudata/  the scene (default office) and its cached triangulation (cache/tri_*), so the
#              check's training step does not spend its time triangulating
# Usage:  bash ci/gpu_pack.sh [SCENE_DIR]        (default ../shared/data/office)
# Then one call of the device tool, carry [".gl", ".whl", ".gpudata"]:
#   TSPLUS_DATA=.gpudata TSPLUS_CACHE=$PWD/.gpudata/cache BUDGET=575 bash ci/gpu_check.sh
# What travels is limited to 64 MiB in all: the sizes are printed at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
scene="${1:-../shared/data/office}"
py="${PYTHON:-.venv/bin/python}"
[ -d "$scene/images" ] || { echo "gpu_pack: $scene/images not found: name a scene folder (TSPLUS_DATA's office)" >&2; exit 2; }
exclude="$(git rev-parse --git-dir)/info/exclude"
mkdir -p "$(dirname "$exclude")"
for d in /.gl/ /.whl/ /.gpudata/; do grep -qxF "$d" "$exclude" 2>/dev/null || echo "$d" >>"$exclude"; done

# the device image has numpy, scipy, opencv, imageio, pillow, tqdm, matplotlib, pytest and
# pytest-xdist (the device tool's KINDS.md); these it lacks
pins=()
for name in wgpu cffi pycparser pycolmap trimesh rendercanvas glfw pillow_heif; do
    pins+=("$name==$("$py" -c "import importlib.metadata as m, sys; print(m.version(sys.argv[1]))" "$name")")
done
platforms=()
for n in 17 24 27 28 31 34 35; do platforms+=(--platform "manylinux_2_${n}_x86_64"); done
rm -rf .whl && mkdir .whl
"$py" -m pip download -q --no-deps --only-binary=:all: --python-version "${GPU_PYTHON:-3.12}" --implementation cp \
    "${platforms[@]}" --platform manylinux2014_x86_64 -d .whl "${pins[@]}"

rm -rf .gl && mkdir .gl
lists=$(mktemp -d)
mkdir -p "$lists/partial"
apt=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$lists")
apt-get "${apt[@]}" update -qq >/dev/null
(cd .gl && apt-get "${apt[@]}" download -qq libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 2>/dev/null)

rm -rf .gpudata && mkdir -p .gpudata/cache
name=$(basename "$(cd "$scene" && pwd)")
cp -r "$scene" ".gpudata/$name" && chmod -R u+w ".gpudata/$name"
cache=$("$py" -c "from tsplus_wgpu.data.sfm import cache_root; print(cache_root()[0])")
found=0
for about in "$cache"/tri_*/about.json; do
    [ -f "$about" ] && [ -f "$(dirname "$about")/points.npz" ] || continue
    src=$("$py" -c "import json, sys; print(json.load(open(sys.argv[1])).get('source') or '')" "$about")
    if [ -n "$src" ] && [ -d "$src" ] && [ "$(cd "$src" && pwd)" = "$(cd "$scene/images" && pwd)" ]; then
        cp -r "$(dirname "$about")" .gpudata/cache/ && found=$((found + 1))
    fi
done
[ "$found" -gt 0 ] || echo "gpu_pack: no cached triangulation of $scene in $cache: train or inspect it here once first, or the check triangulates it there"
tree=$(git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1)
echo "packed: .whl $(du -sh .whl | cut -f1), .gl $(du -sh .gl | cut -f1), .gpudata $(du -sh .gpudata | cut -f1) ($found cache entries);" \
     "with the tracked files $(( (tree + $(du -sb .whl .gl .gpudata | awk '{s += $1} END {print s}')) / 1048576 )) MiB of the 64 MiB that travel"
echo "then one call of the device tool: carry [\".gl\", \".whl\", \".gpudata\"], command" \
     "'TSPLUS_DATA=.gpudata TSPLUS_CACHE=\$PWD/.gpudata/cache BUDGET=575 bash ci/gpu_check.sh', timeout_s 600"
