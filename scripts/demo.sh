#!/usr/bin/env bash
# The README's first command: installs everything, builds, then runs the end-to-end demo on an
# embedded default that needs no data and no display:
#   1. renders a synthetic furnished room with a handheld camera (OSMesa; exact poses and depth),
#   2. runs monocular SLAM on it and evaluates the trajectory against the ground truth (Sim(3) ATE),
#   3. draws the sparse map, keyframes and trajectory to a PNG,
#   4. trains the CPU NeRF on the sequence and renders held-out views next to the real images.
# Usage: scripts/demo.sh [OUT_DIR]   (default: out/demo; NERF_SECONDS=60 sets the NeRF budget)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
bash scripts/build.sh
out=${1:-out/demo}
bin=$root/build/nerfslam
mkdir -p "$out"
start=$(date +%s)

echo "== 1/4 rendering the synthetic room (200 frames, 640x480)"
"$bin" synth --scene room --trajectory handheld --frames 200 --size 640x480 --seed 1 --out "$out/sequence"

echo "== 2/4 monocular SLAM"
"$bin" run --dataset "tum:$out/sequence" --out "$out/slam"
"$bin" eval --ref "$out/sequence/groundtruth.txt" --est "$out/slam/trajectory.txt" --align sim3 \
  --json "$out/slam/eval.json"

echo "== 3/4 map preview"
"$bin" render-preview --points "$out/slam/map_points.ply" --trajectory "$out/slam/trajectory.txt:red" \
  --keyframes "$out/slam/keyframes.txt" --up 0,-1,0 --out "$out/map_preview.png"

echo "== 4/4 NeRF (${NERF_SECONDS:-60} s on the CPU, every 8th view held out)"
"$bin" train --transforms "$out/sequence/transforms.json" --out "$out/nerf" --seconds "${NERF_SECONDS:-60}" \
  --downscale 2

cat <<MSG

Demo finished in $(( $(date +%s) - start )) s. Results in $out:
  slam/report.json       frames tracked, keyframes, map points, timings, ATE against ground truth
  slam/trajectory.txt    estimated camera poses (TUM format); sequence/groundtruth.txt is the truth
  map_preview.png        sparse map, keyframes and trajectory
  nerf/report.json       NeRF test PSNR/SSIM; nerf/*.png held-out renders next to the real images
MSG
