#!/bin/bash
# Issue 25's GPU measurement (docs/benchmarks.md, "On a GPU: the asynchronous runner"): env steps/s of the `async`
# preset with the learner on the GPU and 1..15 rollout workers on the CPU cores, 16 worlds per worker, plus the same
# 15 workers with the learner on the CPU. `tools/gpu_scaling.sh scaling` (about 5.5 minutes on an H200 machine) is the
# sweep over worker counts; `tools/gpu_scaling.sh repeats` (about 4 minutes) repeats the fastest settings. The GPU machine has its own torch and cannot download: put the wheels of
# pymunk, cffi, pycparser, gymnasium, farama-notifications and pettingzoo for its Python in .whl/ first (the header
# of tools/gpu_check.sh). One JSON line per run goes to $OUT/scaling.jsonl (default /tmp/gpu_scaling); the most
# telling worker counts run first, so a run cut short by the device's time limit still has them.
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu_scaling}; mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
UPDATES=${UPDATES:-20}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$OUT/machine.txt"
nproc | tee -a "$OUT/machine.txt"
lscpu | grep -E "Model name|Thread|Core|Socket" | tee -a "$OUT/machine.txt"
git rev-parse --short HEAD 2>/dev/null | tee -a "$OUT/machine.txt"
versions=$(python3 -c "import torch, numpy, pymunk, dynenv_ros.learning.distributed.pool_source
print(torch.__version__, numpy.__version__, pymunk.version, torch.cuda.get_device_name(0))") || exit 1
echo "$versions" | tee -a "$OUT/machine.txt"

bench() {  # label, device, workers, rollouts per update, extra --set arguments...
    local label=$1 device=$2 w=$3 r=$4; shift 4
    local extra=(); for s in "$@"; do extra+=(--set "$s"); done
    local t0=$SECONDS
    timeout 150 python3 -m benchmarks train --config async --device "$device" --baseline none --repeat 1 \
        --updates "$UPDATES" --set workers="$w" --set num_envs=$((16 * w)) --set rollouts_per_update="$r" \
        "${extra[@]}" --json > "$OUT/last.json" 2>> "$OUT/stderr.txt"
    python3 - "$label" "$device" "$w" "$r" "$((SECONDS - t0))" "$*" "$OUT/last.json" >> "$OUT/scaling.jsonl" <<'EOF'
import json, sys
label, device, w, r, seconds, extra, path = sys.argv[1:]
row = {"label": label, "device": device, "workers": int(w), "rollouts_per_update": int(r), "set": extra,
       "call_s": int(seconds)}
try:
    res = next(iter(json.load(open(path))["results"].values()))
    row.update({k: (v["median"] if isinstance(v, dict) else v) for k, v in res.items()
                if k.startswith(("env_steps", "ms_per_update", "policy_lag", "peak_rss", "cpu_s", "wall_s",
                                 "dropped"))})
except Exception as error:  # a failed run is a row too, with its reason
    row["error"] = repr(error)[:300]
print(json.dumps(row))
EOF
    tail -1 "$OUT/scaling.jsonl"
}


case "${1:-scaling}" in
  scaling)
    bench gpu cuda 15 8
    bench gpu cuda 8 4
    bench gpu cuda 4 2
    bench gpu cuda 1 1
    bench gpu-1mb cuda 15 8 ppo_minibatches=1
    bench cpu-learner cpu 15 8
    bench gpu cuda 12 6
    bench gpu cuda 2 1 ;;
  repeats)
    bench gpu-1mb cuda 15 8 ppo_minibatches=1
    bench gpu-1mb cuda 15 8 ppo_minibatches=1
    bench gpu cuda 15 8
    bench gpu-1mb cuda 15 15 ppo_minibatches=1
    bench gpu-1mb cuda 16 8 ppo_minibatches=1
    bench gpu-1mb cuda 16 8 ppo_minibatches=1 ;;
  *) echo "usage: tools/gpu_scaling.sh [scaling|repeats]"; exit 2 ;;
esac
