#!/usr/bin/env bash
# AdvSim's Table 2 at this project's scale, in one command: the learned stack attacked on synthetic
# logs of the training seeds (params/campaign_table2_train.yaml), fine-tuned on its hardest training
# windows (curriculum) and on the adversarial scenarios that campaign found (robust training), then
# the standard, curriculum and robust stacks attacked side by side on held-out test seeds
# (params/campaign_table2.yaml).
#   scripts/table2.sh [OUT]      e.g. scripts/table2.sh out/table2    (WORKERS=2 for two attacks at once)
# Only train-split scenarios are trained on and only test-split ones evaluated (docs/stacks.md;
# tests/stacks/test_table2_split.py). Campaigns resume from their journals, so a stopped run can be
# started again with the same OUT. Run from the repository root.
set -euo pipefail
out=${1:-out/table2}
workers=${WORKERS:-1}
advsim=.venv/bin/advsim
mkdir -p "$out"
"$advsim" campaign params/campaign_table2_train.yaml -o "$out/train_campaign" --workers "$workers"
"$advsim" export training "$out/train_campaign/suite" -o "$out/data"
"$advsim" train-il --scheme curriculum -o "$out/il_planner_curriculum.pt" > "$out/training_curriculum.json"
"$advsim" train-il --scheme robust --adversarial "$out/data" -o "$out/il_planner_robust.pt" > "$out/training_robust.json"
for scheme in curriculum robust; do
  weights=$(realpath "$out/il_planner_$scheme.pt")
  printf '/**:\n  ros__parameters:\n    planner:\n      weights: "%s"\n' "$weights" > "$out/stack_learned_$scheme.yaml"
done
sed -e "s#CURRICULUM_PARAMS#$(realpath "$out/stack_learned_curriculum.yaml")#" \
    -e "s#ROBUST_PARAMS#$(realpath "$out/stack_learned_robust.yaml")#" \
    params/campaign_table2.yaml > "$out/campaign.yaml"
# The standard and robust stacks first, scene by scene (the comparison Table 2 is about), then the
# curriculum stack on the same scenes: a run stopped early has whole pairs, and the same n for both.
grep -v "name: learned_curriculum" "$out/campaign.yaml" > "$out/campaign_robust.yaml"
grep -v -e "^  - learned$" -e "name: learned_robust" "$out/campaign.yaml" > "$out/campaign_curriculum.yaml"
"$advsim" campaign "$out/campaign_robust.yaml" -o "$out/eval" --workers "$workers"
mkdir -p "$out/eval_curriculum" && cp -rn "$out/eval/logs" "$out/eval_curriculum/"  # the same logs, not regenerated
"$advsim" campaign "$out/campaign_curriculum.yaml" -o "$out/eval_curriculum" --workers "$workers"
.venv/bin/python -m advsim_ros.campaign.table2 "$out/eval" "$out/eval_curriculum" | tee "$out/table2.md"
echo "table2: $out/table2.md (each stack original vs adversarial, paired differences); reports in $out/eval*/report.md"
