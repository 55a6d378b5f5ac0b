#!/usr/bin/env bash
# The GPU numbers of docs/benchmarks.md in one run, on a machine with a CUDA GPU and acl3d[gpu,rsl]:
#
#   scripts/gpu_benchmarks.sh OUT [STEPS] [SEEDS]
#
# 1. the CPU batched env on this machine's cores (all but 4), beside
# 2. the many-world simulation on the GPU (scripts/bench_gpu.py: raw physics, env steps/s with
#    rules and resets, a new process's first step; Stump Tracks, then 3D Terrain) on the 4 others;
# 3. rsl-ppo on Stump Tracks (stump-v1's task space, test set and teacher settings; ALP-GMM's
#    refits in a worker process, applied 100 episodes after their fit point) for STEPS
#    env steps (default 20M, TeachMyAgent's budget), ALP-GMM seed 0 alone (its steps/s are the
#    end-to-end figure), then Random and ALP-GMM on the other seeds side by side.
# OUT gets the tables, each run's evals.csv and a summary; runs live in OUT/runs.
set -uo pipefail
out=${1:?usage: scripts/gpu_benchmarks.sh OUT [STEPS] [SEEDS]}
steps=${2:-20000000}
seeds=${3:-2}
mkdir -p "$out/runs"
cores=$(nproc)
command -v taskset >/dev/null || taskset() { shift 2; "$@"; }  # no pinning where it is missing
taskset -c 4-$((cores - 1)) python3 scripts/bench_batched.py --steps 3000 --sizes 1 256 \
  --threads $((cores - 4)) --rounds 1 --max-subproc 0 >"$out/cpu_batched.txt" 2>&1 &
cpu=$!
taskset -c 0-3 python3 scripts/bench_gpu.py --device cuda --sizes 4096 16384 --steps 100 \
  --first-step --json "$out/bench_gpu.json" 2>&1 | grep -v '^Module' | tee "$out/bench_gpu.txt"
taskset -c 0-3 python3 scripts/bench_gpu.py --device cuda --env terrain3d --sizes 4096 16384 \
  --steps 100 --json "$out/bench_gpu_terrain3d.json" 2>&1 | grep -v '^Module' \
  | tee "$out/bench_gpu_terrain3d.txt"
wait $cpu

train() {  # teacher seed
  local params=()
  [ "$1" = alp-gmm ] && params=(--teacher-param fit_rate=150 --teacher-param fit_lag=100)
  python3 -m acl3d train "${params[@]}" --student rsl-ppo --preset benchmark --device cuda --n-envs 4096 \
    --env stump-tracks --body classic_bipedal --bounds stump_height=0,3 \
    --bounds obstacle_spacing=0,6 --expert-knowledge low --test-set grid \
    --nb-test-episodes 100 --eval-stochastic --eval-every $((steps / 8)) \
    --checkpoint-every $((steps / 2)) --teacher "$1" --seed "$2" --steps "$steps" \
    --no-progress --out "$out/runs/$1-s$2" >"$out/train-$1-s$2.txt" 2>&1
}
train alp-gmm 0
for seed in $(seq 0 $((seeds - 1))); do
  for teacher in random alp-gmm; do
    [ "$teacher-$seed" = alp-gmm-0 ] || train "$teacher" "$seed" &
  done
done
wait
for run in "$out"/runs/*/; do
  echo "$(basename "$run"): $(tail -n 1 "$run/evals.csv")"
done | tee "$out/training.txt"
