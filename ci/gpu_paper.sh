#!/usr/bin/env bash
# One whole paper-preset run on a lent GPU, across calls of the device tool (issue 13, item 4):
# a scene (default office) as the GPU plan trains it, into runs/gpu-paper, which git ignores, so
# a warm machine keeps it between calls. Each call trains for at most LIMIT seconds (default
# 540); then SIGTERM writes the checkpoint, and the next call resumes it. Once the run has
# finished, its metrics.json, log.jsonl, config.json and a held-out render come back.
#
#   TSPLUS_DATA=.gpudata TSPLUS_CACHE=$PWD/.gpudata/cache LIMIT=540 bash ci/gpu_paper.sh [SCENE_DIR]
#
# (carry .gl, .whl and .gpudata: `bash ci/gpu_pack.sh` packs them). Writes gpu_paper.log and
# the run's files under $OUT/gpu-paper (else ./gpu-paper). Nothing here asserts a timing.
set -u
cd "$(dirname "$0")/.."
out="${OUT:+$OUT/gpu-paper}"
out="${out:-gpu-paper}"
mkdir -p "$out"
log="$out/gpu_paper.log"
: >"$log"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}" PYTHONUNBUFFERED=1
source ci/gpu_env.sh     # the loader, the driver's ICD, the interpreter and the wheels: sets py
scene="${1:-${TSPLUS_DATA:-../shared/data}/office}"
run=runs/gpu-paper
limit="${LIMIT:-540}"
resume=()
if [ -f "$run/metrics.json" ]; then
    echo "== $run has finished: its files only" | tee -a "$log"
else
    [ -f "$run/checkpoint.npz" ] && resume=(--resume)
    echo "== $(date -u +%H:%M:%S) train $scene ${resume[*]:-from the start} for at most $limit s" \
         "(load $(cut -d' ' -f1-3 /proc/loadavg); $(nvidia-smi -L 2>/dev/null | head -1))" | tee -a "$log"
    # -k 60: after SIGTERM the step in flight finishes and the checkpoint is written
    timeout -k 60 "$limit" "$py" -m tsplus_wgpu.cli.main train "$scene" --seed 0 --no-progress --out "$run" \
        "${resume[@]}" >>"$log" 2>&1
    echo "== exit $? at $(date -u +%H:%M:%S)" | tee -a "$log"
fi
for f in metrics.json log.jsonl config.json test_008.png; do
    [ -f "$run/$f" ] && cp "$run/$f" "$out/"
done
grep -h "plan:\|estimate\|held-out PSNR\|SIGTERM\|error" "$log" | tail -8
