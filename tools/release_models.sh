#!/usr/bin/env bash
# How the shipped models were made (docs/EVALUATION.md): two or three phases per model
# on CPU, 1 torch thread each, the three models trained side by side.
#   phase 1: 128 px crops, cosine schedule from LR1;  phase 2: 256 px, from phase 1's weights;
#   phase 3 (STEPS3 > 0, models named in P3_MODELS): 256 px from phase 2's weights, light tint TINT3.
# Usage: tools/release_models.sh OUT_DIR DATA_DIR [DATA_DIR...]
# Env: STEPS1 STEPS2 STEPS3 (per model), LR1 LR2 LR3, TINT3, P3_MODELS, BATCH.
set -euo pipefail
out=$1; shift
data=("$@")
py=${PY:-.venv/bin/python}
STEPS1=${STEPS1:-1600}; STEPS2=${STEPS2:-100}; LR1=${LR1:-5e-4}; LR2=${LR2:-1.5e-4}; BATCH=${BATCH:-4}
STEPS3=${STEPS3:-0}; LR3=${LR3:-1e-4}; TINT3=${TINT3:-0.25}; P3_MODELS=${P3_MODELS:-"default kanamori-endo"}

train_phases() {  # NAME, then extra model.train flags; a rerun skips finished phases, resumes phase 1
  local name=$1; shift
  local resume=()
  [[ -f "$out/$name/p1/checkpoints/last.ckpt" ]] && resume=(--resume)
  [[ -f "$out/$name/p1/model.safetensors" ]] || "$py" -m model.train --data "${data[@]}" --out "$out/$name/p1" --steps "$STEPS1" --batch "$BATCH" \
      --size 128 --threads 1 --lr "$LR1" --lr-schedule cosine --warmup 100 \
      --val-every 1000 --ckpt-every 250 --cache-scenes 160 --quiet "${resume[@]}" "$@"
  [[ -f "$out/$name/p2/model.safetensors" ]] || "$py" -m model.train --data "${data[@]}" --out "$out/$name/p2" --steps "$STEPS2" --batch "$BATCH" \
      --size 256 --threads 1 --lr "$LR2" --lr-schedule cosine --warmup 20 \
      --init "$out/$name/p1/model.safetensors" --val-every "$STEPS2" --ckpt-every 50 --cache-scenes 160 --quiet "$@"
  [[ "$STEPS3" -gt 0 && " $P3_MODELS " == *" $name "* ]] || return 0
  "$py" -m model.train --data "${data[@]}" --out "$out/$name/p3" --steps "$STEPS3" --batch "$BATCH" \
      --size 256 --threads 1 --lr "$LR3" --lr-schedule cosine --warmup 20 --light-tint "$TINT3" \
      --init "$out/$name/p2/model.safetensors" --val-every 1000 --ckpt-every 100 --cache-scenes 160 --quiet "$@"
}

mkdir -p "$out"
train_phases default --preset default > "$out/default.log" 2>&1 &
train_phases small --preset small > "$out/small.log" 2>&1 &
# Kanamori-Endo-style comparison: Lambertian PRT targets, N=2, no residual, same layout and budget
train_phases kanamori-endo --preset default --lambertian --order 2 > "$out/kanamori-endo.log" 2>&1 &
wait
