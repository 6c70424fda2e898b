#!/usr/bin/env bash
# AdvSim's Table 2 at this project's scale: the learned stack fine-tuned on its hardest real training
# windows (curriculum) and on the failures a campaign found (robust training), then attacked beside the
# standard one on held-out scenarios.
#   scripts/table2.sh FOUND_CAMPAIGN_DIR [OUT]     e.g. scripts/table2.sh out/campaign_kitti out/table2
# FOUND_CAMPAIGN_DIR is an `advsim campaign` output with a suite/ (params/campaign_kitti.yaml makes one);
# only failures of the training split are trained on, and curriculum windows come from the training
# split only (docs/stacks.md). Run from the repository root.
set -euo pipefail
found=${1:?usage: scripts/table2.sh FOUND_CAMPAIGN_DIR [OUT]}
out=${2:-out/table2}
advsim=.venv/bin/advsim
mkdir -p "$out"
"$advsim" export training "$found/suite" -o "$out/data"
"$advsim" train-il --scheme curriculum -o "$out/il_planner_curriculum.pt" > "$out/training_curriculum.json"
"$advsim" train-il --scheme robust --adversarial "$out/data" -o "$out/il_planner_robust.pt" > "$out/training_robust.json"
for scheme in curriculum robust; do
  weights=$(realpath "$out/il_planner_$scheme.pt")
  printf '/**:\n  ros__parameters:\n    planner:\n      weights: "%s"\n' "$weights" > "$out/stack_learned_$scheme.yaml"
done
sed -e "s#CURRICULUM_PARAMS#$(realpath "$out/stack_learned_curriculum.yaml")#" \
    -e "s#ROBUST_PARAMS#$(realpath "$out/stack_learned_robust.yaml")#" \
    params/campaign_table2.yaml > "$out/campaign.yaml"
"$advsim" campaign "$out/campaign.yaml" -o "$out/eval" --workers 2
echo "table2: the standard, curriculum and robust rows of Table 1 in $out/eval/report.md are Table 2"
