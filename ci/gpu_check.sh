#!/usr/bin/env bash
# The measurements a session lent a GPU should take first (issue 13, item 4), as one command
# that fits one call of the device tool: the benchmarks in every kernel layout, the whole test
# suite, and a training run of a shared real scene. Steps run in order of value; each has a
# time limit, cut to what is left of the budget, and a step with under 15 s left is skipped and
# says so. Nothing here asserts a timing.
#
#   bash ci/gpu_check.sh [OUT_DIR]        (default: $OUT/gpu-check, else ./gpu-check)
#
# Environment: BUDGET seconds in all (default 540); TSPLUS_DATA the real scenes (office is
# trained when it is there); TSPLUS_CACHE (an absolute path) a carried cache holding office's
# triangulation (without it the training steps triangulate first and may not finish); PYTHON
# the interpreter (default: .venv/bin/python if present, else python3); TSPLUS_ADAPTER as usual.
# On a bare machine that has Python and numpy but not this package's other dependencies (no
# wgpu there), put their wheels (for that machine's Python) in .whl/ and the Vulkan loader's
# .deb files in .gl/: they are unpacked first (the loader into /, as root).
# Writes gpu_check.log (every step's output, with its time and the load), gpu_check.json (every
# benchmark's JSON, the test counts, the quick run's metrics and the paper run's rows) and
# office_paper_log.jsonl. `bash ci/gpu_pack.sh` packs, here, what a bare machine needs.
set -u
cd "$(dirname "$0")/.."
out="${1:-${OUT:+$OUT/gpu-check}}"
out="${out:-gpu-check}"
mkdir -p "$out"
parts=$(mktemp -d)
log="$out/gpu_check.log"
budget="${BUDGET:-540}"
start=$(date +%s)
: >"$log"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}" PYTHONUNBUFFERED=1

source ci/gpu_env.sh     # the loader, the driver's ICD, the interpreter and the wheels: sets py
echo "== $(nproc) cores; $(nvidia-smi -L 2>/dev/null | head -1)" | tee -a "$log"

# step NAME LIMIT_S COMMAND...: COMMAND under LIMIT_S, or what is left of the budget
step() {
    local name="$1" limit="$2"
    shift 2
    local left=$((budget - ($(date +%s) - start) - 10))
    [ "$limit" -gt "$left" ] && limit=$left
    if [ "$limit" -lt 15 ]; then
        echo "== $name: skipped ($left s left of the budget)" | tee -a "$log"
        return
    fi
    echo "== $name ($(date -u +%H:%M:%S), limit $limit s, load $(cut -d' ' -f1-3 /proc/loadavg)): $*" | tee -a "$log"
    local t0 rc
    t0=$(date +%s)
    timeout -k 5 "$limit" "$@" >>"$log" 2>&1
    rc=$?
    echo "== $name: exit $rc after $(($(date +%s) - t0)) s" | tee -a "$log"
}

ts=("$py" -m tsplus_wgpu.cli.main)     # the tsplus command, as an array timeout can run

step adapters 30 "${ts[@]}" adapters
for layout in gpu cpu; do       # the forward: gpu and pixel share one kernel
    step "bench-raster $layout" 50 "${ts[@]}" bench-raster --triangles 100000 1000000 --repeats 5 --layout "$layout" \
        --json "$parts/raster-$layout.json"
done
for layout in gpu cpu pixel; do
    step "bench-backward $layout" 40 "${ts[@]}" bench-backward --repeats 5 --layout "$layout" \
        --json "$parts/backward-$layout.json"
done
# the suite: one thread a worker (NumPy's threads in 14 workers made a load of 89 on 16 cores)
workers=$(( $(nproc) > 4 ? $(nproc) - 2 : 1 ))
[ "$workers" -gt 14 ] && workers=14
if "$py" -c "import xdist" 2>/dev/null && [ "$workers" -gt 1 ]; then
    xdist=(-n "$workers" --dist loadgroup)
else
    xdist=()
fi
step "test suite" 200 env OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 "$py" -m pytest -q -p no:cacheprovider -ra \
    "${xdist[@]}" -o junit_family=xunit2 --junitxml "$parts/tests.xml"
data="${TSPLUS_DATA:-../shared/data}"
if [ -d "$data/office" ]; then
    step "train office (the CPU plan's run: quick 2,300 at 240x135)" 200 "${ts[@]}" train "$data/office" \
        --preset quick --iterations 2300 --downscale 4 --seed 0 --no-progress --overwrite --out "$parts/office"
else
    echo "== train office: skipped ($data/office not found; set TSPLUS_DATA)" | tee -a "$log"
fi
for layout in gpu pixel cpu; do
    step "bench-scale $layout" 60 "${ts[@]}" bench-scale --vertices 500k 1M --repeats 2 --layout "$layout" \
        --json "$parts/scale-$layout.json"
done
step bench-step 40 "${ts[@]}" bench-step
# last, for what is left of the budget: office as a new user on a GPU trains it (the GPU plan:
# the paper preset at full size), cut by the budget; its log.jsonl says the rate between
# topology edits and what each edit cost (SIGTERM writes the checkpoint, as it should)
if [ -d "$data/office" ]; then
    step "train office, the GPU plan (paper preset, full size), for what is left" 100000 "${ts[@]}" train "$data/office" \
        --seed 0 --no-progress --overwrite --out "$parts/office-paper"
    cp "$parts/office-paper/log.jsonl" "$out/office_paper_log.jsonl" 2>/dev/null
fi
"$py" - "$parts" "$out" <<'EOF' >>"$log" 2>&1
import json, pathlib, sys
import xml.etree.ElementTree as ET
parts, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
doc = {p.stem: json.loads(p.read_text()) for p in sorted(parts.glob("*.json"))}
if (parts / "tests.xml").exists():
    root = ET.parse(parts / "tests.xml").getroot()
    suite = root if root.tag == "testsuite" else root[0]
    doc["tests"] = {k: suite.get(k) for k in ("tests", "failures", "errors", "skipped", "time")}
    doc["tests"]["failed"] = [f"{c.get('classname')}::{c.get('name')}: {(f.get('message') or '')[:300]}"
                              for c in suite.iter("testcase") for f in c if f.tag in ("failure", "error")]
    print("tests:", json.dumps(doc["tests"], indent=1))
m = parts / "office" / "metrics.json"
if m.exists():
    doc["office_metrics"] = json.loads(m.read_text())
log = parts / "office-paper" / "log.jsonl"
if log.exists():    # the rows (iteration, seconds, model) and the topology edits
    rows = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    doc["office_paper"] = [{k: r[k] for k in ("iteration", "elapsed", "vertices", "triangles", "event", "split",
                                              "pruned_opacity", "pruned_weight", "pruned_size") if k in r}
                           for r in rows]
(out / "gpu_check.json").write_text(json.dumps(doc, indent=1, default=str))
print("wrote", out / "gpu_check.json", "with", ", ".join(doc) or "nothing")
EOF
echo "== done in $(($(date +%s) - start)) s" | tee -a "$log"
