#!/usr/bin/env bash
# How the relighting models of issue 45 are made: one every-framing training from scratch on the
# scale45 campaign (model.campaign: every framing, 30 % hard lights, seed 4500; resumable from
# ~/.cache/relight/campaigns/scale45), the level prior calibrated on training-light scenes, and the
# look-pool evaluation (docs/EVALUATION.md, "The curve in width and data").
# Usage: tools/release_scale45.sh OUT_DIR PRESET SCENES [REGISTER_AS [--default]]
#   e.g. tools/release_scale45.sh runs/r45 geo-default 1320 geometry --default
#        tools/release_scale45.sh runs/r45s geo-small 1320 geometry-small
# env: STEPS (6000), BATCH (8), THREADS (2), DEVICE (auto), PY; MORE_STEPS (0): trains on from the
#   first run's weights for this many steps more (a warm restart: lr 5e-4 cosine, seed 2);
#   TRAIN_FLAGS: more model.train options for both, e.g. "--loss-weight sun_response=1";
#   MORE_FLAGS: more options for the warm restart alone (after the others: they override them);
#   AVERAGE (unset): ships the weights this share of the way from the first run's to the restart's
#   (python -m model.average; needs MORE_STEPS).
# The shipped model of 2026-11-28 (evening): MORE_STEPS=3000 AVERAGE=0.5 THREADS=1
#   MORE_FLAGS="--loss-weight sun_response=1 --seed 3 --warmup 100" tools/release_scale45.sh runs/r45 \
#   geo-default 2640 geometry --default
# The farm's scenes are made here, on the CPU; a GPU trains from the pack (model.train --device cuda).
set -euo pipefail
out=$1; preset=$2; scenes=$3; name=${4:-}; default=${5:-}
py=${PY:-.venv/bin/python}
STEPS=${STEPS:-6000}; BATCH=${BATCH:-8}; THREADS=${THREADS:-2}; DEVICE=${DEVICE:-auto}; MORE_STEPS=${MORE_STEPS:-0}
campaign=${RELIGHT_CAMPAIGNS:-$HOME/.cache/relight/campaigns}/scale45
mkdir -p "$out"

# the campaign's scenes (only rendering: --pack-only; a rerun continues), a calibration set under
# training lights, and the two look-pool sets (held-out maps; the unfamiliar one also held-out looks)
"$py" -m model.campaign --name scale45 --scenes 5292 --seed 4500 --res 128 --lights 2 --samples 16 \
    --framing all --hard-lights 0.3 --farm-workers 2 --size 128 --steps 1 --pack-only
"$py" -m farm --out "$out/calib45" --scenes 96 --seed 3711 --res 128 --lights 2 --samples 16 --order 4 \
    --framing all --hard-lights 0.3 --workers 2 --resume --no-progress
for look in train heldout; do
    "$py" -m farm --out "$out/look_$look" --scenes 48 --seed 4545 --res 128 --lights 2 --samples 32 \
        --hard-lights 0.5 --framing head-and-shoulders,waist-up,full-body --light-pool heldout \
        --look-pool "$look" --workers 2 --resume --no-progress
done
# head-and-shoulders under held-out maps and looks, 4 lights, half of them hard: 116 map -> side-sun pairs
"$py" -m farm --out "$out/sun_hs" --scenes 160 --seed 4547 --res 128 --lights 4 --samples 16 \
    --framing head-and-shoulders --light-pool heldout --look-pool heldout --hard-lights 0.5 --workers 2 \
    --resume --no-progress

resume() { [[ -f "$1/checkpoints/last.ckpt" ]] && echo --resume || true; }
# what both trainings share: the scenes, the pack, the network and the recipe but for steps, lr and seed
train=("$py" -m model.train --data "$campaign/farm" --max-scenes "$scenes" --pack "$out/pack.npz" --preset "$preset"
       --size 128 --batch "$BATCH" --lr-schedule cosine --warmup 200 --light-tint 0.15 --fit-stride 2 --front-facing
       --threads "$THREADS" --val-every 100000 --ckpt-every 250 --device "$DEVICE" --quiet ${TRAIN_FLAGS:-})
"${train[@]}" --out "$out/run" --steps "$STEPS" --lr 1e-3 --seed 1 $(resume "$out/run") > "$out/train.log" 2>&1

weights="$out/run/model.safetensors"; how="from scratch"
if (( MORE_STEPS > 0 )); then
    "${train[@]}" --out "$out/run_more" --steps "$MORE_STEPS" --lr 5e-4 --seed 2 --init "$weights" \
        $(resume "$out/run_more") ${MORE_FLAGS:-} > "$out/train_more.log" 2>&1
    how="from scratch, then $MORE_STEPS steps more from those weights (lr 5e-4 cosine, seed 2${MORE_FLAGS:+, $MORE_FLAGS})"
    if [[ -n "${AVERAGE:-}" ]]; then
        "$py" -m model.average "$weights" "$out/run_more/model.safetensors" --weight "$AVERAGE" \
            --out "$out/run_average/model.safetensors"
        weights="$out/run_average/model.safetensors"
        how="$how, the weights $AVERAGE of the way from the first's to those (python -m model.average)"
    else
        weights="$out/run_more/model.safetensors"
    fi
fi
onnx="$out/model.onnx"
register=()
if [[ -n "$name" ]]; then
    onnx="relight/models/${name//-/_}.onnx"
    register=(--register "$name" $default)
fi
"$py" -m export "$weights" --out "$onnx" "${register[@]}" --training-data "relight farm: \
the first $scenes scenes of the scale45 campaign (every framing, 30 % hard lights, 2 lights, 16 spp, 128 px, \
seed 4500); GeometryNet $preset, $STEPS steps of batch $BATCH on 128 px crops, lr 1e-3 cosine, light tint 0.15, \
fit stride 2, front-facing${TRAIN_FLAGS:+, $TRAIN_FLAGS}, $how (tools/release_scale45.sh)"
"$py" -m export.level_prior "$onnx" --data "$out/calib45" --mixed-lights --write
for look in train heldout; do
    "$py" -m model.evaluate "$onnx" --data "$out/look_$look" --size 128 --out "$out/eval_$look"
done
"$py" -m model.compare_sets "$out/eval_train" "$out/eval_heldout" --labels familiar unfamiliar
PYTHONPATH=. "$py" benchmarks/bench_framing_presets.py --data "$out/sun_hs" --side-sun --model "$onnx"
