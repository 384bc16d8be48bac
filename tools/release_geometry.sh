#!/usr/bin/env bash
# How the geometry-first model was made (docs/EVALUATION.md, "Geometry-first model"):
# render the training and held-out data, train the geometry-first model and, with the
# same data and budget, the paper's decomposition (RelightNet) beside it, 1 torch
# thread each, then export the geometry model as the registry's default.
# Usage: tools/release_geometry.sh OUT_DIR   (env: SCENES, STEPS, BATCH, PY)
set -euo pipefail
out=$1
py=${PY:-.venv/bin/python}
SCENES=${SCENES:-400}; STEPS=${STEPS:-1000}; BATCH=${BATCH:-8}
mkdir -p "$out"

# data: 128 px training scenes (2 lights, 32 spp: docs/benchmarks/farm_render.md), 256 px held-out scenes (held-out maps only)
"$py" -m farm --out "$out/train128" --scenes "$SCENES" --seed 1 --res 128 --lights 2 --samples 32 \
    --workers 2 --resume --no-progress
"$py" -m farm --out "$out/heldout256" --scenes 24 --seed 777001 --res 256 --lights 4 --samples 32 \
    --workers 1 --light-pool heldout --resume --no-progress

common=(--data "$out/train128" --size 128 --steps "$STEPS" --batch "$BATCH" --lr 1e-3 --lr-schedule cosine
        --warmup 100 --val-every 300 --ckpt-every 100 --quiet --pack "$out/pack.npz" --light-tint 0.15
        --threads 1)
resume() { [[ -f "$1/checkpoints/last.ckpt" ]] && echo --resume || true; }
# the pack is made once by the first run; start the second when it exists
"$py" -m model.train --out "$out/geometry" --preset geo-default "${common[@]}" $(resume "$out/geometry") \
    > "$out/geometry.log" 2>&1 &
while [[ ! -f "$out/pack.npz" ]]; do sleep 10; done
"$py" -m model.train --out "$out/paper-decomposition" --preset default "${common[@]}" \
    $(resume "$out/paper-decomposition") > "$out/paper-decomposition.log" 2>&1 &
wait

"$py" -m export "$out/geometry/model.safetensors" --out relight/models/geometry.onnx --register geometry \
    --default --training-data "relight farm, $(ls "$out"/train128/scene_*.json | wc -l) scenes at 128 px (2 lights, 32 spp), seed 1; GeometryNet geo-default, $STEPS steps of batch $BATCH on 128 px crops, CPU (tools/release_geometry.sh)"
