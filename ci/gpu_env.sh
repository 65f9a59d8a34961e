# Sourced by ci/gpu_check.sh and ci/gpu_paper.sh, from the repository root, with $log set: on
# a bare device machine, unpacks the Vulkan loader's .deb files from .gl/ (as root), points
# Vulkan at the NVIDIA driver's ICD, picks the interpreter ($PYTHON, else .venv/bin/python, else
# python3) into $py and, where it lacks this package's dependencies, installs the wheels in .whl/
# into a temporary folder on PYTHONPATH (with the checkout). `bash ci/gpu_pack.sh` packs both.
if compgen -G ".gl/*.deb" >/dev/null && [ "$(id -u)" = 0 ]; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -f "$icd" ] && [ -z "${VK_DRIVER_FILES:-}" ]; then export VK_DRIVER_FILES="$icd"; fi
py="${PYTHON:-}"
if [ -z "$py" ]; then
    if [ -x .venv/bin/python ]; then py=.venv/bin/python; else py=python3; fi
fi
if ! "$py" -c "import wgpu, pycolmap, trimesh" 2>/dev/null && compgen -G ".whl/*.whl" >/dev/null; then
    site=$(mktemp -d)
    "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" .whl/*.whl >>"$log" 2>&1 \
        || echo "== the wheels in .whl/ did not install (see above)" | tee -a "$log"
    export PYTHONPATH="$site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
fi
