#!/usr/bin/env bash
# The Reacher pair's experiments reported in docs/results.md, as plain `pved` commands
# (until `pved protocol` runs the paper's protocol in one command). Two runs at a time,
# one core each; every stage skips finished runs and resumes unfinished ones, so the
# script can be restarted after an interruption. About 2 hours on 2 cores.
#
#   bash scripts/reacher_experiments.sh
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1
P=.venv/bin/pved
JOBS=${JOBS:-2}
M=runs/reacher/model/pved/seed0/model.pt
B=runs/reacher/bank/Reacher3-Push/seed0/bank.npz
TUNING="2000 4000 6000"
EVALUATION="20000 40000 60000 80000 100000"
parallel() { xargs -P "$JOBS" -I{} sh -c "$P {} > /dev/null"; }

# 1. the preset's stages: 1000 paired Reach episodes, PVED (100 epochs), a 200-episode bank
$P collect-pairs --pair reacher
$P train-model --pair reacher --model pved
$P build-bank --pair reacher

# 2. beta on three of the paper's tuning seeds, 500k steps each
for beta in 0.1 0.01 0.001; do
  for s in $TUNING; do
    echo "transfer --runs runs/beta/$beta --model pved --seed $s --beta $beta --steps 500000 --model-path $M --bank $B"
  done
done | parallel

# 3. the evaluation seeds at 1M steps: PVED at the selected beta, plain PPO
for s in $EVALUATION; do
  echo "transfer --runs runs/eval --model pved --beta 0.001 --seed $s --model-path $M --bank $B"
  echo "transfer --runs runs/eval --model ppo --seed $s"
done | parallel

# 4. DTW alignment (2 rounds) instead of subsampling, then the same transfer; the oracle
$P collect-pairs --pair reacher --align dtw
$P train-model --pair reacher --model pved --runs runs/dtw --dataset runs/reacher/pairs/dtw/seed0/pairs.npz
for s in $EVALUATION; do
  echo "transfer --runs runs/dtw --model pved --beta 0.001 --seed $s --model-path runs/dtw/reacher/model/pved/seed0/model.pt --bank $B"
done | parallel
for s in $EVALUATION; do echo "transfer --runs runs/eval --model oracle --seed $s"; done | parallel

# 5. reports
$P report --runs runs/eval --pair reacher --methods pved ppo oracle --seeds $EVALUATION --out reports/reacher-1m
$P report --runs runs/dtw --pair reacher --methods pved --seeds $EVALUATION --out reports/reacher-1m-dtw
