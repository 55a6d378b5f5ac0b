#!/usr/bin/env bash
# The GPU numbers of docs/benchmarks.md, stage by stage, on a machine with a CUDA GPU and
# acl3d[gpu,rsl] (a lent machine runs the stages over a few calls; each writes under OUT):
#
#   scripts/gpu_benchmarks.sh cpu OUT      # the CPU path on this machine's cores 4..: the batched
#                                          # env (1 and 256 envs), SB3 PPO and rsl-ppo training
#   scripts/gpu_benchmarks.sh env OUT [ENV [BODY]]
#                                          # the many-world simulation at 4,096 and 16,384
#                                          # worlds (stump-tracks: and a new process's first
#                                          # step; terrain3d: big_quadru; parkour: BODY, e.g.
#                                          # classic_bipedal in water, climbing_profile_chimpanzee)
#   scripts/gpu_benchmarks.sh levers OUT [ROWS] [SLOTS]
#                                          # 3D Terrain's big quadruped at 16,384 worlds with
#                                          # MuJoCo Warp's reservations and with fewer constraint
#                                          # rows (default 192) and contact slots (default 24)
#                                          # per world, alone and together
#   scripts/gpu_benchmarks.sh kernels OUT  # where a physics step's device time goes, kernel by
#                                          # kernel: 3D Terrain's big quadruped and Stump
#                                          # Tracks at 16,384 worlds (the heightfield's share)
#   scripts/gpu_benchmarks.sh terrain OUT  # 3D Terrain's raw physics at 16,384 worlds on other
#                                          # grids, with its blocks as box geoms, and
#                                          # laid out as the env does (a draw a world,
#                                          # MuJoCo Warp's reservations)
#   scripts/gpu_benchmarks.sh tiles OUT    # 3D Terrain's raw physics at 16,384 worlds, timed
#                                          # after 40 and after 120 steps (bodies lying down):
#                                          # each world's field only as tall as its ground, and
#                                          # cut into 2 m and 1 m tiles; then the kernels after
#                                          # 120 steps
#   scripts/gpu_benchmarks.sh grids OUT    # 3D Terrain's big quadruped through the env at
#                                          # 16,384 worlds on its grid (0.1 x 0.5 m) and on
#                                          # others (grid_spacing 0.1 x 0.2, 0.1 x 0.4, 0.2 x 0.2
#                                          # and 0.5 x 0.5 m), then its kernels on three
#   scripts/gpu_benchmarks.sh speed OUT [STEPS] [WORLDS] [FIT_LAG]
#                                          # one ALP-GMM run alone: steps/s end to end, its phases
#                                          # (10 evaluations, played side by side at the end)
#   scripts/gpu_benchmarks.sh teachers OUT [STEPS]
#                                          # Robust PLR, SPDL and the setter-solver alone at
#                                          # 4,096 worlds (default 2M steps): the teacher's share
#   scripts/gpu_benchmarks.sh update OUT   # rsl-ppo's update alone, rsl_rl's PPO against LeanPPO
#                                          # (benchmark preset, 4,096 and 16,384 worlds)
#   scripts/gpu_benchmarks.sh actions OUT  # the evaluator's actions a step: a forward a
#                                          # snapshot against one stack (10 x 100 worlds)
#   scripts/gpu_benchmarks.sh repeat OUT   # the same run twice and a resumed one (1M steps)
#   scripts/gpu_benchmarks.sh learn OUT [SEED...]
#                                          # stump-v2's Random and ALP-GMM cells of these seeds
#                                          # (default 0 1), one after the other (campaign run +
#                                          # export); a later call with other seeds adds cells
#   scripts/gpu_benchmarks.sh summary OUT  # every run's last evaluation and phases
#   scripts/gpu_benchmarks.sh pack OUT     # OUT's results in one file, OUT/results.tgz: every
#                                          # run without checkpoints and TensorBoard files, its
#                                          # teacher dump included (what `campaign export` needs)
#
# The runs use stump-v2's settings (acl3d/campaign/specs/stump-v2.yaml): Stump Tracks [0, 3] x
# [0, 6], classic biped, rsl-ppo's benchmark preset, 4,096 worlds, the 100-task grid with
# sampled actions, ALP-GMM with fit_lag 100.
set -uo pipefail
stage=${1:?usage: scripts/gpu_benchmarks.sh cpu|env|levers|kernels|terrain|tiles|grids|speed|teachers|update|actions|repeat|learn|summary|pack OUT ...}
out=${2:?usage: scripts/gpu_benchmarks.sh STAGE OUT ...}
mkdir -p "$out/runs"
cores=$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)  # nproc alone counts OMP_NUM_THREADS
command -v taskset >/dev/null || taskset() { shift 2; "$@"; }  # no pinning where it is missing

train() {  # teacher seed steps worlds eval_every fit_lag [extra args...]
  local teacher=$1 seed=$2 steps=$3 worlds=$4 every=$5 lag=$6 params=()
  shift 6
  [ "$teacher" = alp-gmm ] && params=(--teacher-param "fit_lag=$lag")
  python3 -m acl3d train "${params[@]}" --student rsl-ppo --preset benchmark --device cuda \
    --n-envs "$worlds" --env stump-tracks --body classic_bipedal --bounds stump_height=0,3 \
    --bounds obstacle_spacing=0,6 --expert-knowledge low --test-set grid \
    --nb-test-episodes 100 --eval-stochastic --eval-every "$every" \
    --periodical-samples-every 1000000 --checkpoint-every $((steps / 2)) --teacher "$teacher" \
    --seed "$seed" --steps "$steps" --no-progress "$@"
}

case $stage in
cpu)
  taskset -c 4-$((cores - 1)) python3 scripts/bench_batched.py --steps 3000 --sizes 1 256 \
    --threads $((cores - 4)) --rounds 1 --max-subproc 0 >"$out/cpu_batched.txt" 2>&1
  taskset -c 4-$((cores - 1)) python3 scripts/bench_training.py --students ppo \
    --batched-envs 64 256 --rsl-envs 64 256 --ppo-steps 65536 >"$out/cpu_training.txt" 2>&1
  ;;
env)
  env=${3:-stump-tracks}
  extra=()
  [ "$env" = stump-tracks ] && extra=(--first-step)
  [ "$env" = terrain3d ] && extra=(--body big_quadru)
  [ -n "${4:-}" ] && extra=(--body "$4")
  python3 scripts/bench_gpu.py --device cuda --env "$env" --sizes 4096 16384 --steps 100 \
    "${extra[@]}" --json "$out/bench_gpu_$env${4:+_$4}.json" 2>&1 | grep -v '^Module' \
    | tee "$out/bench_gpu_$env${4:+_$4}.txt"
  ;;
levers)  # what 3D Terrain's raw physics, which bounds its env, gains from smaller reservations
  python3 scripts/bench_gpu.py --device cuda --env terrain3d --body big_quadru --sizes 16384 \
    --steps 100 --constraint-rows 0 "${3:-192}" --contact-slots 0 "${4:-24}" \
    --json "$out/bench_gpu_levers.json" 2>&1 | grep -v '^Module' | tee "$out/bench_gpu_levers.txt"
  ;;
kernels)  # why 3D Terrain's raw physics is slower than Stump Tracks' (kernel shares)
  for env in "terrain3d --body big_quadru" stump-tracks; do
    # shellcheck disable=SC2086  # env holds the family and its body
    python3 scripts/profile_warp_kernels.py --device cuda --env $env --worlds 16384 --steps 20 \
      --constraint-rows 192 --contact-slots 24
  done 2>&1 | grep -v '^Module' | tee "$out/kernels.txt"
  ;;
terrain)  # what other terrain geometry would gain 3D Terrain's raw physics
  python3 scripts/bench_terrain3d_collision.py --device cuda --worlds 16384 --steps 50 \
    --rounds 1 2>&1 | grep -v '^Module' | tee "$out/terrain.txt"
  ;;
tiles)  # whether a GPU pays the slowest collision thread, which tiles would shorten
  {
    python3 scripts/bench_terrain3d_collision.py --device cuda --worlds 16384 --steps 50 \
      --warmup 40 120 --rounds 1 --variants 6 9 10 11
    python3 scripts/profile_warp_kernels.py --device cuda --env terrain3d --body big_quadru \
      --worlds 16384 --steps 20 --warmup 120 --constraint-rows 192 --contact-slots 24
  } 2>&1 | grep -v '^Module' | tee "$out/tiles.txt"
  ;;
grids)  # what a coarser grid (Terrain3DEnv's grid_spacing) gains the env, rules and resets in
  for spacing in 0.1,0.5 0.1,0.2 0.1,0.4 0.2,0.2 0.5,0.5; do
    python3 scripts/bench_gpu.py --device cuda --env terrain3d --body big_quadru --sizes 16384 \
      --steps 100 --env-kwarg "grid_spacing=[$spacing]" \
      --json "$out/bench_gpu_terrain3d_grid_${spacing/,/x}.json" 2>&1 | grep -v '^Module'
  done | tee "$out/grids.txt"
  # the heightfield kernel on each grid after 40 steps: does it follow the prisms sent to GJK
  # (10.1, 17.4 and 10.9 a world on Warp's CPU device, scripts/hfield_work.py)?
  for spacing in 0.1,0.5 0.1,0.2 0.2,0.2; do
    python3 scripts/profile_warp_kernels.py --device cuda --env terrain3d --body big_quadru \
      --worlds 16384 --steps 20 --constraint-rows 192 --contact-slots 24 --top 3 \
      --env-kwarg "grid_spacing=[$spacing]"
  done 2>&1 | grep -v '^Module' | tee -a "$out/grids.txt"
  ;;
speed)
  steps=${3:-20000000} worlds=${4:-16384} lag=${5:-600}
  train alp-gmm 0 "$steps" "$worlds" $((steps / 10)) "$lag" --out "$out/runs/speed-$worlds" \
    >"$out/speed-$worlds.txt" 2>&1
  tail -n 3 "$out/speed-$worlds.txt"
  ;;
teachers)  # the teacher's share of a run at 4,096 worlds, for the teachers with the most work
  # per step (Robust PLR, SPDL: every world's step) or per task (the setter-solver's flow)
  steps=${3:-2000000}
  for teacher in robust-plr self-paced setter-solver; do
    train "$teacher" 0 "$steps" 4096 "$steps" 0 --out "$out/runs/teacher-$teacher" \
      >"$out/teacher-$teacher.txt" 2>&1
    tail -n 2 "$out/teacher-$teacher.txt"
  done
  ;;
update)  # whether LeanPPO's update costs more than rsl_rl's on a GPU (same rollout and weights)
  for worlds in 4096 16384; do
    python3 scripts/bench_rsl_update.py --device cuda --preset benchmark --worlds "$worlds" \
      --rounds 5
  done 2>&1 | tee "$out/update.txt"
  ;;
actions)  # what acting as one stack saves the evaluation pass a step (launches, host time)
  python3 scripts/bench_policy_stack.py --device cuda 2>&1 | tee "$out/actions.txt"
  ;;
repeat)  # same seed twice, and the same run stopped at 500k and resumed, side by side
  for name in a b; do
    train alp-gmm 5 1000000 4096 500000 100 --out "$out/runs/repeat-$name" \
      >"$out/repeat-$name.txt" 2>&1 &
  done
  train alp-gmm 5 500000 4096 500000 100 --out "$out/runs/repeat-resumed" \
    >"$out/repeat-resumed.txt" 2>&1 &&
    python3 -m acl3d train --resume "$out/runs/repeat-resumed" --steps 1000000 --no-progress \
      >>"$out/repeat-resumed.txt" 2>&1
  wait
  for other in b resumed; do
    python3 scripts/compare_runs.py "$out/runs/repeat-a" "$out/runs/repeat-$other"
  done | tee "$out/repeat.txt"
  ;;
learn)  # stump-v2's Random and ALP-GMM cells of the given seeds, one at a time (runs side by
  # side time-slice the GPU: four at once ran slower in all than one alone), then exported
  shift 2
  seeds=("$@") only=()
  [ ${#seeds[@]} -eq 0 ] && seeds=(0 1)
  for seed in "${seeds[@]}"; do only+=(--only "seed=$seed"); done
  python3 -m acl3d campaign run stump-v2 --out "$out/stump-v2" --executor local \
    --max-parallel 1 --only teacher=random --only teacher=alp-gmm "${only[@]}" \
    >>"$out/learn.txt" 2>&1
  python3 -m acl3d campaign export "$out/stump-v2" --protocol stump-v2 --out "$out/export" \
    >>"$out/learn.txt" 2>&1
  ;;
summary)
  for run in "$out"/runs/*/ "$out"/stump-v2/runs/*/; do
    echo "$(basename "$run"): $(tail -n 1 "$run/evals.csv" 2>/dev/null)"
    python3 -c "import json,sys; s=json.load(open(sys.argv[1])); print('  ', s['status'], \
s.get('seconds_by_phase'))" "$run/status.json" 2>/dev/null
  done | tee "$out/summary.txt"
  ;;
pack)
  packed=$(mktemp)
  tar czf "$packed" --exclude=checkpoints --exclude=tb --exclude=results.tgz -C "$out" . &&
    mv "$packed" "$out/results.tgz"
  ;;
*)
  echo "unknown stage $stage: cpu, env, levers, speed, teachers, update, repeat, learn, summary or pack" >&2
  exit 2
  ;;
esac
