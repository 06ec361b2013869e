#!/usr/bin/env bash
# The README's first command: installs everything, builds, then runs the whole system on its
# embedded default, which needs no data and no display: `nerfslam run` without a dataset renders a
# synthetic furnished room with a handheld camera (OSMesa; exact poses and depth), tracks it with
# monocular SLAM while the NeRF mapping thread trains on the keyframes, then evaluates the
# trajectory (Sim(3) ATE against the ground truth) and the NeRF (held-out frames, depth) and draws
# the map and the trajectory to PNGs.
# Usage: scripts/demo.sh [OUT_DIR]   (default: out/demo; DEMO_FRAMES=300 sets the sequence length)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
bash scripts/build.sh
out=${1:-out/demo}
start=$(date +%s)
"$root/build/nerfslam" run --out "$out" --demo-frames "${DEMO_FRAMES:-300}"

cat <<MSG

Demo finished in $(( $(date +%s) - start )) s. Results in $out:
  report.json          frames tracked, keyframes, timings, ATE against ground truth, NeRF PSNR and depth error
  map_preview.png      sparse map, NeRF cloud, keyframes and trajectory
  trajectory.png       the estimated trajectory (Sim(3)-aligned) against the ground truth
  nerf/heldout/*.png   NeRF renders of frames it never trained on | the real images
  nerf/model.nerf      the NeRF map (render it: build/nerfslam render --model $out/nerf/model.nerf ...)
  nerf_cloud.ply/.pcd, mesh.ply, map_points.ply, trajectory.txt (TUM), map/ (the saved map folder)
MSG
