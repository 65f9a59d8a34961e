#!/usr/bin/env bash
# The measurements a session lent a GPU should take first (issue 13, item 4), as one command
# that fits one call of the device tool: both kernel layouts in the forward, backward and scale
# benchmarks, the kernel tests in both layouts, and a training run of a shared real scene in
# the adapter's own layout. Every step has its own time limit and the whole a budget; a step
# that would not fit in what is left is skipped and says so. Nothing here asserts a timing.
#
#   bash ci/gpu_check.sh [OUT_DIR]        (default: $OUT/gpu-check, else ./gpu-check)
#
# Environment: BUDGET seconds in all (default 540); TSPLUS_DATA the real scenes (office is
# trained when it is there); PYTHON the interpreter that imports tsplus_wgpu and its
# dependencies (default: .venv/bin/python if present, else python3); TSPLUS_ADAPTER as usual.
# Writes gpu_check.log (every step's output, with its time), gpu_check.json (every benchmark's
# JSON and the run's metrics in one document) and tests.log: three files, within what the
# device tool brings back.
set -u
cd "$(dirname "$0")/.."
out="${1:-${OUT:+$OUT/gpu-check}}"
out="${out:-gpu-check}"
mkdir -p "$out/parts"
log="$out/gpu_check.log"
budget="${BUDGET:-540}"
py="${PYTHON:-}"
if [ -z "$py" ]; then
    if [ -x .venv/bin/python ]; then py=.venv/bin/python; else py=python3; fi
fi
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
start=$(date +%s)
: >"$log"

# step NAME LIMIT_S COMMAND...: runs COMMAND under LIMIT_S if it fits the budget left
step() {
    local name="$1" limit="$2"
    shift 2
    local left=$((budget - ($(date +%s) - start)))
    if [ "$limit" -gt "$left" ]; then
        echo "== $name: skipped ($limit s needed, $left s left of the budget)" | tee -a "$log"
        return
    fi
    echo "== $name ($(date -u +%H:%M:%S), limit $limit s): $*" | tee -a "$log"
    local t0 rc
    t0=$(date +%s)
    timeout -k 5 "$limit" "$@" >>"$log" 2>&1
    rc=$?
    echo "== $name: exit $rc after $(($(date +%s) - t0)) s" | tee -a "$log"
}

ts=("$py" -m tsplus_wgpu.cli.main)     # the tsplus command, as an array timeout can run

step adapters 30 "${ts[@]}" adapters
"$py" -c "import os; print('load average', os.getloadavg())" >>"$log" 2>&1
for layout in cpu gpu; do
    step "bench-raster $layout" 60 "${ts[@]}" bench-raster --triangles 100000 1000000 --repeats 5 --layout "$layout" \
        --json "$out/parts/raster-$layout.json"
done
for layout in cpu gpu; do
    step "bench-backward $layout" 45 "${ts[@]}" bench-backward --repeats 5 --layout "$layout" \
        --json "$out/parts/backward-$layout.json"
done
for layout in cpu gpu; do
    step "bench-scale $layout" 75 "${ts[@]}" bench-scale --vertices 500k 1M --repeats 2 --layout "$layout" \
        --json "$out/parts/scale-$layout.json"
done
step "kernel tests, both layouts" 120 "$py" -m pytest -q -p no:cacheprovider tests/kernels -x \
    -o "junit_family=xunit2" --junitxml "$out/parts/tests.xml"
grep -E "passed|failed|error" "$log" | tail -1 >"$out/tests.log"
data="${TSPLUS_DATA:-../shared/data}"
if [ -d "$data/office" ]; then
    step "train office (quick 2,300 at 240x135, the adapter's layout)" 200 "${ts[@]}" train "$data/office" \
        --preset quick --iterations 2300 --downscale 4 --seed 0 --no-progress --out "$out/parts/office"
else
    echo "== train office: skipped ($data/office not found; set TSPLUS_DATA)" | tee -a "$log"
fi
"$py" - "$out" <<'EOF' >>"$log" 2>&1
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
doc = {}
for p in sorted((out / "parts").glob("*.json")):
    doc[p.stem] = json.loads(p.read_text())
m = out / "parts" / "office" / "metrics.json"
if m.exists():
    doc["office_metrics"] = json.loads(m.read_text())
(out / "gpu_check.json").write_text(json.dumps(doc, indent=1, default=str))
print("wrote", out / "gpu_check.json", "with", ", ".join(doc) or "nothing")
EOF
echo "== done in $(($(date +%s) - start)) s" | tee -a "$log"
