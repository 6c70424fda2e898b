#!/usr/bin/env bash
# AdvSim's Table 2 at this project's scale, in one command:
#   1. Table 2's standard learned stack trained from scratch on the training split: the training
#      seeds' street logs and their logs of the interaction families (params/stack_learned_table2.yaml);
#   2. that stack attacked on the training seeds' logs (params/campaign_table2_train.yaml), every
#      attack's best scenario exported as training samples;
#   3. fine-tuned on its hardest training windows (curriculum) and on those found scenarios (robust);
#   4. the standard, curriculum, robust and reference stacks attacked side by side on held-out test
#      seeds, every failure replayed on the other stacks (params/campaign_table2.yaml), then on the
#      Argoverse 2 logs with simulated LiDAR (params/campaign_table2_av2.yaml), and the table.
#   scripts/table2.sh [OUT]      e.g. scripts/table2.sh out/table2    (WORKERS=2 for two attacks at once)
# TRAINING_SEED=N trains every stack with training.seed N (another draw of the same training); one OUT per seed,
# then `advsim campaign-table2 OUT_A/eval OUT_B/eval` pools them, each pairing within its own run.
# Only train-split scenarios are trained on and only test-split ones evaluated (docs/stacks.md;
# tests/stacks/test_table2_split.py). Campaigns resume from their journals, so a stopped run can be
# started again with the same OUT. Run from the repository root.
set -euo pipefail
out=${1:-out/table2}
workers=${WORKERS:-1}
advsim=.venv/bin/advsim
if [[ -n "${TRAINING_SEED:-}" && ! "$TRAINING_SEED" =~ ^[0-9]+$ ]]; then
  echo "table2: TRAINING_SEED must be a whole number, got '$TRAINING_SEED'" >&2
  exit 2
fi
mkdir -p "$out"
training="$out/stack_learned_table2.yaml"  # params/stack_learned_table2.yaml, with the training seed if one is given
if [[ -n "${TRAINING_SEED:-}" ]]; then
  { cat params/stack_learned_table2.yaml; printf '      seed: %s\n' "$TRAINING_SEED"; } > "$training.tmp"
else
  cp params/stack_learned_table2.yaml "$training.tmp"
fi
if [[ -f "$training" ]] && ! cmp -s "$training" "$training.tmp"; then
  rm -f "$training.tmp"
  echo "table2: $out was trained with other parameters ($training); give another OUT" >&2
  exit 2
fi
mv "$training.tmp" "$training"
stack_params() {  # Table 2's training parameters and the weights of one scheme, for train-il and the stack node
  { cat "$training"; printf '    planner:\n      weights: "%s"\n' "$(realpath "$out/il_planner_$1.pt")"; } \
    > "$out/stack_learned_$1.yaml"
}
if [[ ! -f "$out/il_planner_standard.pt" ]]; then
  "$advsim" train-il --params "$training" -o "$out/il_planner_standard.pt" > "$out/training_standard.json"
fi
stack_params standard
fill() { sed -e "s#STANDARD_PARAMS#$(realpath "$out/stack_learned_standard.yaml")#" \
             -e "s#CURRICULUM_PARAMS#$(realpath "$out/stack_learned_curriculum.yaml")#" \
             -e "s#ROBUST_PARAMS#$(realpath "$out/stack_learned_robust.yaml")#" "$1"; }
fill params/campaign_table2_train.yaml > "$out/campaign_train.yaml"
"$advsim" campaign "$out/campaign_train.yaml" -o "$out/train_campaign" --workers "$workers"
"$advsim" export training "$out/train_campaign/suite" -o "$out/data" --params "$out/stack_learned_standard.yaml"
if [[ ! -f "$out/il_planner_curriculum.pt" ]]; then  # weights are written whole (renamed into place) or not at all
  "$advsim" train-il --scheme curriculum --params "$out/stack_learned_standard.yaml" -o "$out/il_planner_curriculum.pt" \
    > "$out/training_curriculum.json"
fi
if [[ ! -f "$out/il_planner_robust.pt" ]]; then
  "$advsim" train-il --scheme robust --adversarial "$out/data" --params "$out/stack_learned_standard.yaml" \
    -o "$out/il_planner_robust.pt" > "$out/training_robust.json"
fi
stack_params curriculum
stack_params robust
fill params/campaign_table2.yaml > "$out/campaign.yaml"
"$advsim" campaign "$out/campaign.yaml" -o "$out/eval" --workers "$workers"
evals=("$out/eval")
# Real traffic: the Argoverse 2 logs of the shared data with a simulated LiDAR sweep every frame (test split)
av2_logs=(../shared/data/av2/*-*-*-*-*/)
if [[ -d "${av2_logs[0]}" ]]; then
  mkdir -p "$out/av2"
  for log in "${av2_logs[@]}"; do
    id=$(basename "$log")
    bag="$out/av2/av2_${id%%-*}"
    [[ -d "$bag" ]] || "$advsim" convert av2 "$log" --lidar simulate -o "$bag"
  done
  fill params/campaign_table2_av2.yaml > "$out/campaign_av2.yaml"  # beside av2/: its bags are relative to it
  "$advsim" campaign "$out/campaign_av2.yaml" -o "$out/eval_av2" --workers "$workers"
  evals+=("$out/eval_av2")
else
  echo "table2: no Argoverse 2 logs in ../shared/data/av2: the table has the synthetic test scenes only" >&2
fi
"$advsim" campaign-table2 "${evals[@]}" -o "$out/table2.md"
echo "table2: $out/table2.md (each stack original vs adversarial, paired differences, per scene family);" \
  "generalisation: Table 3 (transfer) of report.md in ${evals[*]}"
