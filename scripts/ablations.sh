#!/usr/bin/env bash
# Network ablations of issue 4 (paper Tables IX/X): trains four short runs with the same seed,
# data and step count, then benchmarks them together with the shipped model in one
# `sgreg bench-match` run. Resumable: a finished run is skipped, an interrupted one resumes.
#   source env/activate && scripts/ablations.sh [STEPS]
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-600}
declare -A variants=(
  [late]=""                                    # the paper's design (and the shipped model's)
  [no_triplets]="--set model.gnn.use_triplets=false"
  [no_shape]="--set model.fusion=none"
  [early]="--set model.fusion=early"
)
names=(late no_triplets no_shape early)
for name in "${names[@]}"; do
  dir=runs/abl_${name}_${steps}     # the step count in the name: runs of other lengths are not "done"
  if [[ -f $dir/model.safetensors ]]; then echo "== $name: done"; continue; fi
  resume=""; [[ -f $dir/checkpoint.pt ]] && resume="--resume"
  echo "== $name: training $steps steps into $dir"
  # shellcheck disable=SC2086
  sgreg train --config config/train.yaml --set optim.steps="$steps" --set run_dir="$dir" \
    ${variants[$name]} $resume
done
weights=(); for name in "${names[@]}"; do weights+=("runs/abl_${name}_${steps}/model.safetensors"); done
sgreg bench-match --weights "${weights[@]}" sgreg_core/weights/sgreg.safetensors \
  --names "${names[@]/%/_${steps}}" shipped_2000 --out results/bench_match.json
