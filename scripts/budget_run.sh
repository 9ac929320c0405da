#!/usr/bin/env bash
# The budget run of issue 39 (docs/model.md, "The budget run"): the sixth stage's eight datasets and a
# network trained from a random draw, data and training within 6 CPU-hours on a 2-core machine.
#   1. the data: the eight sets, with the commands and seeds the GPU campaign's recipe uses (one list,
#      pipelines/gpu_campaign/options.py), made here on the CPU;
#   2. stage A: config lrrep_span (or $CONFIG) from a random draw, lr 1e-3 cosine over 9,000 steps (TOTAL_STEPS) of batch 4 of
#      32 x 32 (two one-thread processes);
#   (a stage B, batch 8 of 48 x 48 from stage A, was measured and did not pay: docs/model.md).
# Usage: bash scripts/budget_run.sh; DATA=DIR and RUNS=DIR choose the folders (data/ and runs/budget/),
# CONFIG=NAME the config of stage A (lrrep_span; lrrep_span_shot is the loss lever's long run),
# DATA_VARIANT=NAME adds that variant's training sets (pipelines/gpu_campaign/options.py,
# BUDGET_DATA_VARIANTS; "natdark": 24 dark natural scenes; "procedural": 40 procedural scenes, lrrep_v1's
# kind, the best budget data measured, with CONFIG=lrrep_span_shot_direct TOTAL_STEPS=11000);
# TOTAL_STEPS=N trains N steps instead of the measured runs' 9,000;
# DIRECT_STEPS=N trains the first N of the 9,000 steps as the config's direct twin ($DIRECT_CONFIG, by
# default ${CONFIG}_direct: no refining gates) in $RUNS/d, then the rest as $CONFIG from its best.pt;
# HEAD_STEPS=N adds a last stage of N steps: $HEAD_CONFIG (by default ${CONFIG%_direct}_head) from the
# network's best.pt, the head widened with the refining gates and trained alone on the frozen body
# (train.trainable "head"), in $RUNS/h; HEAD_STEPS=1500 after CONFIG=lrrep_span_shot_direct was
# measured on three seeds and changed nothing on average (docs/model.md, "The head on a frozen direct
# network, and a third seed");
# SEED=N draws the network and the data order from another seed (11, the measured runs'; each later
# stage takes the next seed), for the spread between runs;
# DRY_RUN=1 prints the commands instead of running them.
# Interrupt it at any point and run it again: `generate` resumes each dataset, `train --resume`
# each stage bit for bit, and a finished stage says "nothing to do". It prints the CPU time its
# commands took (bash's `times`), to compare with the budget.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
S=.venv/bin/spikesim
RUN=()
[ -n "${DRY_RUN:-}" ] && RUN=(echo)
DATA="${DATA:-data}"
RUNS="${RUNS:-runs/budget}"
CONFIG="${CONFIG:-lrrep_span}"
export DATA_VARIANT="${DATA_VARIANT:-}"
TOTAL_STEPS="${TOTAL_STEPS:-9000}"
# the measured runs' length; a longer run is the budget's other lever: a step costs about 1.7 CPU-seconds
# (two one-thread processes, fp32, measured on a 2-core AMD EPYC), so the 6 CPU-hours less the
# data's 0.44 hold about 11,700 steps (docs/model.md, "The budget run")
if ! { [[ "$TOTAL_STEPS" =~ ^[1-9][0-9]*$ ]] && [ "$TOTAL_STEPS" -ge 2 ] && [ "$TOTAL_STEPS" -le 100000 ]; }; then
  echo "TOTAL_STEPS=$TOTAL_STEPS: expected a whole number of training steps from 2 to 100000" >&2
  exit 2
fi
SEED="${SEED:-11}"
if ! { [[ "$SEED" =~ ^(0|[1-9][0-9]*)$ ]] && [ "$SEED" -le 1000000 ]; }; then
  echo "SEED=$SEED: expected a whole number from 0 to 1000000" >&2
  exit 2
fi
DIRECT_STEPS="${DIRECT_STEPS:-}"
DIRECT_CONFIG="${DIRECT_CONFIG:-${CONFIG}_direct}"
if [ -n "$DIRECT_STEPS" ]; then
  if ! { [[ "$DIRECT_STEPS" =~ ^[1-9][0-9]*$ ]] && [ "$DIRECT_STEPS" -ge 1 ] && [ "$DIRECT_STEPS" -lt "$TOTAL_STEPS" ]; }; then
    echo "DIRECT_STEPS=$DIRECT_STEPS: expected a whole number of steps from 1 to $((TOTAL_STEPS - 1)) (of the run's $TOTAL_STEPS)" >&2
    exit 2
  fi
  # the direct stage's config must exist before hours of data are made for it
  $PY -c "import sys; from model.config import load_config; load_config(sys.argv[1])" "$DIRECT_CONFIG" >/dev/null || {
    echo "DIRECT_CONFIG=$DIRECT_CONFIG: no such config (DIRECT_STEPS needs the direct twin of CONFIG=$CONFIG)" >&2
    exit 2
  }
fi
HEAD_STEPS="${HEAD_STEPS:-}"
HEAD_CONFIG="${HEAD_CONFIG:-${CONFIG%_direct}_head}"
if [ -n "$HEAD_STEPS" ]; then
  if ! { [[ "$HEAD_STEPS" =~ ^[1-9][0-9]*$ ]] && [ "$HEAD_STEPS" -le 100000 ]; }; then
    echo "HEAD_STEPS=$HEAD_STEPS: expected a whole number of steps from 1 to 100000" >&2
    exit 2
  fi
  # the head stage starts from the network before it (--init): the same network but for its head's
  # output, checked before hours of data are made for it
  $PY - "$CONFIG" "$HEAD_CONFIG" <<'EOF' || exit 2
import dataclasses, sys
from model.config import load_config
try:
    net, head = load_config(sys.argv[1]).model, load_config(sys.argv[2])
except (OSError, ValueError) as exc:
    sys.exit(f"HEAD_CONFIG={sys.argv[2]}: {exc}")
if dataclasses.replace(net, output=head.model.output, refine_span=head.model.refine_span) != head.model:
    sys.exit(f"HEAD_CONFIG={sys.argv[2]}: its network is not CONFIG={sys.argv[1]}'s with another head, "
             "so it cannot start from that network's weights")
if head.train.trainable == "all":
    sys.exit(f"HEAD_CONFIG={sys.argv[2]}: it trains every weight (train.trainable 'all'); the head stage trains "
             "the head on the frozen body ('head' or 'gates')")
EOF
fi
WORKERS="${WORKERS:-2}"
export OMP_NUM_THREADS=1
[ -z "${DRY_RUN:-}" ] && mkdir -p "$DATA" "$RUNS"

# name, role and generate arguments of each set, without the campaign's --workers; the natural sets
# first, the order of the measured run's --data and --val-data (a sample's order depends on it)
# in $(...), not <(...), so that a bad DATA_VARIANT stops the script (set -e)
SETS_TEXT=$($PY - <<'EOF'
import os, sys
from pipelines.gpu_campaign.options import BUDGET_DATA_VARIANTS, PROFILES
variant = os.environ["DATA_VARIANT"]
if variant and variant not in BUDGET_DATA_VARIANTS:
    sys.exit(f"DATA_VARIANT={variant!r}: expected one of {sorted(BUDGET_DATA_VARIANTS)} or nothing")
sets = PROFILES["gpu"].recipe_sets + (BUDGET_DATA_VARIANTS[variant] if variant else ())
for name, role, args in sorted(sets, key=lambda s: ("_nat" not in s[0], sets.index(s))):
    a = list(args)
    if "--workers" in a:
        i = a.index("--workers")
        del a[i:i + 2]
    print(name, role, " ".join(a))
EOF
)
mapfile -t SETS <<< "$SETS_TEXT"
TRAIN=() VAL=()
for line in "${SETS[@]}"; do
  read -r name role args <<< "$line"
  # shellcheck disable=SC2086  # the arguments are plain words
  "${RUN[@]}" $S generate rllr $args --workers "$WORKERS" --quiet -o "$DATA/$name"
  if [ "$role" = train ]; then TRAIN+=("$DATA/$name"); else VAL+=("$DATA/$name"); fi
  echo "[budget] data: $DATA/$name ($role)"
done

train_stage() {  # CONFIG, OUT, then the stage's own flags; resumes a stage that has a last.pt
  local config=$1 out=$2; shift 2
  local how=("$@")
  if [ -f "$out/last.pt" ]; then how=(--resume); fi
  # --keep-validated: every validated checkpoint is kept (validated/), beside each scene's scores
  # (val_scenes.csv), so the network can be picked by another rule afterwards (spikesim pick-checkpoint)
  "${RUN[@]}" .venv/bin/torchrun --standalone --nproc_per_node 2 "$S" train --config "$config" --threads 1 --quiet \
    --keep-validated \
    --data "${TRAIN[@]}" --val-data "${VAL[@]}" "${how[@]}" -o "$out"
}
if [ -z "$DIRECT_STEPS" ]; then
  train_stage "$CONFIG" "$RUNS/a" --lr 1e-3 --max-steps "$TOTAL_STEPS" --seed "$SEED"
else
  # the same $TOTAL_STEPS steps in two stages: the config's direct twin from the random draw, then the
  # config itself from its best.pt (the head widened with the gates), a second cosine cycle at
  # the lineage's fine-tuning rate and another data order
  train_stage "$DIRECT_CONFIG" "$RUNS/d" --lr 1e-3 --max-steps "$DIRECT_STEPS" --seed "$SEED"
  train_stage "$CONFIG" "$RUNS/a" --init "$RUNS/d/best.pt" --lr 3e-4 --max-steps $((TOTAL_STEPS - DIRECT_STEPS)) --seed $((SEED + 1))
fi
NET="$RUNS/a/best.pt"
if [ -n "$HEAD_STEPS" ]; then
  # the head on the frozen body of the network above, from its best.pt, with the next seed
  train_stage "$HEAD_CONFIG" "$RUNS/h" --init "$NET" --lr 1e-3 --max-steps "$HEAD_STEPS" \
    --seed $((SEED + 1 + (${#DIRECT_STEPS} > 0)))
  NET="$RUNS/h/best.pt"
fi
echo "[budget] the network is $NET (score it with --methods budget=$NET)"
# `times` in the script's own shell: in a pipeline or $(...) it runs in a subshell, which ran nothing
echo "[budget] CPU time (user, system): first this script's shell, then the commands it ran (children):"
times
