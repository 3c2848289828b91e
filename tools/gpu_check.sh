#!/bin/bash
# --device cuda end to end on a GPU machine (docs/benchmarks.md, "On a GPU"): CPU/GPU parity, dynenv-bench train on
# both, train + resume + a CPU evaluation of the policy, driving and snapshot opponents on the GPU. That machine has
# its own torch and cannot download: put the wheels of pymunk, cffi, pycparser, gymnasium, farama-notifications and
# pettingzoo for its Python in .whl/ first. Results go to $OUT (default /tmp/gpu_check).
set -x
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu_check}; mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
python3 -c "import torch, numpy, numba; print(torch.__version__, numpy.__version__, numba.__version__, torch.cuda.get_device_name(0))"
timeout 90 python3 tools/device_parity.py 2>&1 | tail -30 | tee $OUT/parity.txt
timeout 100 python3 -m benchmarks train --device cuda --json 2>&1 | tail -40 > $OUT/bench_a2c_cuda.txt; tail -12 $OUT/bench_a2c_cuda.txt
timeout 60 python3 -m benchmarks train --device cpu --updates 10 --json 2>&1 | tail -40 > $OUT/bench_a2c_cpu.txt; tail -12 $OUT/bench_a2c_cpu.txt
timeout 100 python3 -m benchmarks train --config ppo --updates 4 --warmup 1 --device cuda --json 2>&1 | tail -40 > $OUT/bench_ppo_cuda.txt; tail -12 $OUT/bench_ppo_cuda.txt
timeout 90 python3 -m dynenv_ros.learning.train_cli --config quick --device cuda --set total_env_steps=600 --run-dir /tmp/r --no-progress 2>&1 | tail -6
timeout 90 python3 -m dynenv_ros.learning.train_cli --resume /tmp/r --set total_env_steps=1200 --no-progress 2>&1 | tail -6
ls /tmp/r; grep -c . /tmp/r/metrics.csv
timeout 90 python3 -m dynenv_ros.evaluation.cli /tmp/r/policy.safetensors --opponent random --episodes 1 --seeds 0 --players-per-team 2 --quiet 2>&1 | tail -8
timeout 90 python3 -m dynenv_ros.learning.train_cli --config driving_quick --device cuda --set total_env_steps=300 --set action_mode=continuous --run-dir /tmp/d --no-progress 2>&1 | tail -6
timeout 60 python3 -m dynenv_ros.learning.train_cli --config ppo --device cuda --set opponent=snapshot --set snapshot_every_updates=1 --set num_envs=2 --set backend=inprocess --set total_env_steps=256 --run-dir /tmp/p --no-progress 2>&1 | tail -6
# The asynchronous runner with the learner on the GPU against the number of CPU workers (issue 25) is
# tools/gpu_scaling.sh: a call of its own, since each of the two takes most of a 10-minute device command.
