#!/usr/bin/env bash
# How the shipped relighting model is made (issue 25; successor of tools/release_geometry.sh):
# render the training and held-out data, train the geometry-first network on both cores with
# the light fit on every second pixel (docs/benchmarks/model.md), export it as the registry's
# default and evaluate it on the held-out scenes.
# Usage: tools/release.sh OUT_DIR   (env: STEPS, BATCH, THREADS, PY)
# The shipped weights (2026-11-25) were trained before --front-facing existed and exported with it
# switched on in their config (weights unchanged; held-out results identical, docs/EVALUATION.md).
# A GPU runs it too (model.train --device cuda); the data and the pack are made here, on the CPU.
set -euo pipefail
out=$1
py=${PY:-.venv/bin/python}
STEPS=${STEPS:-6000}; BATCH=${BATCH:-8}; THREADS=${THREADS:-2}
mkdir -p "$out"

# data: 441 + 882 training scenes at 128 px (2 lights, 16 spp; two seeds), 24 held-out scenes at
# 256 px (held-out maps only); --resume keeps what a killed run finished
"$py" -m farm --out "$out/train128" --scenes 441 --seed 1 --res 128 --lights 2 --samples 16 \
    --workers 2 --resume --no-progress
"$py" -m farm --out "$out/train128b" --scenes 882 --seed 2 --res 128 --lights 2 --samples 16 \
    --workers 2 --resume --no-progress
"$py" -m farm --out "$out/heldout256" --scenes 24 --seed 777001 --res 256 --lights 4 --samples 32 \
    --workers 1 --light-pool heldout --resume --no-progress

resume() { [[ -f "$1/checkpoints/last.ckpt" ]] && echo --resume || true; }
"$py" -m model.train --data "$out/train128" "$out/train128b" --out "$out/geometry" --preset geo-default \
    --size 128 --steps "$STEPS" --batch "$BATCH" --lr 1e-3 --lr-schedule cosine --warmup 200 \
    --light-tint 0.15 --fit-stride 2 --front-facing --threads "$THREADS" --seed 1 --val-every 1000 --ckpt-every 250 \
    --pack "$out/pack.npz" --quiet $(resume "$out/geometry") > "$out/geometry.log" 2>&1

"$py" -m export "$out/geometry/model.safetensors" --out relight/models/geometry.onnx --register geometry \
    --default --training-data "relight farm, $(ls "$out"/train128/scene_*.json "$out"/train128b/scene_*.json | wc -l) scenes at 128 px (2 lights, 16 spp; seeds 1 and 2); GeometryNet geo-default, light fit on every second pixel, $STEPS steps of batch $BATCH on 128 px crops, lr 1e-3 cosine, light tint 0.15, CPU, $THREADS threads (tools/release.sh)"
"$py" -m model.evaluate relight/models/geometry.onnx --data "$out/heldout256" --size 128 --out "$out/eval"
