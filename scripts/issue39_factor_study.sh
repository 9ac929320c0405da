#!/usr/bin/env bash
# The fifth stage's two changes one factor at a time (docs/model.md, "The fifth stage, one factor at a
# time"): the span gate (config lrrep_span against lrrep_refine) and the still-camera photo sets (data
# STILL against OLD), a 2 x 2 design, each cell fine-tuned from the fourth stage's weights (lrrep_v3)
# for the same number of steps with 3 seeds, scored on the validation scenes (no test set).
# Usage: bash scripts/issue39_factor_study.sh [STEPS]; resumable (compare keeps finished runs).
set -euo pipefail
cd "$(dirname "$0")/.."
S=.venv/bin/spikesim
STEPS="${1:-400}"
OUT="${OUT:-runs/factor_study}"
OLD=data/rllr_nat8tr+data/rllr_photo48+data/rllr_photo_bright48
STILL=$OLD+data/rllr_photo_still48+data/rllr_photo_bright_still48
COMMON=(--test-data data/val_nat8+data/val_photo8 --init lrrep_v3 --seeds 0 1 2 --max-steps "$STEPS"
        --precision fp32 --baselines tfp tfi tfp:205 --jobs 2 --threads 2 --quiet)
for cfg in lrrep_refine lrrep_span; do
  $S compare --data OLD=$OLD STILL=$STILL --configs $cfg "${COMMON[@]}" -o "$OUT/$cfg"
  echo "[factor-study] $cfg done"
done
# For information only (nothing is chosen by it): every run on the seed-7717 LLR at 64 x 100, where
# the still-background scenes (ball, car, fan in normal light) were the fourth stage's losses.
if [ -d data/llr_small5_s7717 ]; then
  M=""
  for cfg in lrrep_refine lrrep_span; do for d in OLD STILL; do for s in 0 1 2; do
    M="$M ${cfg#lrrep_}_${d}_$s=$OUT/$cfg/runs/$d/seed$s/last.pt"
  done; done; done
  $S evaluate --data data/llr_small5_s7717 --methods tfp tfp:123 tfp:205 $M -o "$OUT/llr_s7717" --quiet \
    > "$OUT/llr_s7717.md"
  echo "[factor-study] scored every run on data/llr_small5_s7717"
fi
