#!/usr/bin/env bash
# The dense map's benchmark (issue 21's table): a whole `nerfslam run` on each shared sequence with the
# defaults plus the holdout settings, printing held-out PSNR, SSIM, the NeRF's depth error against the
# map points seen from the held-out frames and against ground-truth depth where the dataset has it.
# With --baseline, the same runs with another build's binary (the previous build), alternating with
# this one sequence by sequence so both see the same machine.
#
#   scripts/bench_dense_map.sh [--baseline OLD/nerfslam] [--steps N] [--only "kitti temple ..."] [--out DIR]
#
#   sequences: kitti (KITTI 06, 51 frames), tsukuba (New Tsukuba 150), temple (Middlebury temple ring),
#              fountain (Strecha fountain-P11), room (the synthetic room, 600 frames), demo (300 frames)
#   --steps N  a fixed number of final training steps (nerf.final_train_steps) instead of 60 s: figures
#              that do not move with the machine's load (the online phase still does)
#
# Data: NERFSLAM_DATA_DIR or ../shared/data beside the repository; a sequence whose data is missing is
# skipped with a message. Needs a build (scripts/build.sh). Each run's outputs stay in DIR/<seq>-<build>.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bin=$root/build/nerfslam
data=${NERFSLAM_DATA_DIR:-$root/../shared/data}
baseline="" steps=0 only="kitti tsukuba temple fountain room demo" out=$root/out/bench_dense
while [[ $# -gt 0 ]]; do
  case $1 in
    --baseline) baseline=$2; shift 2 ;;
    --steps) steps=$2; shift 2 ;;
    --only) only=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    *) echo "bench_dense_map.sh: unknown argument '$1' (see the header of $0)" >&2; exit 2 ;;
  esac
done
[[ -x $bin ]] || { echo "bench_dense_map.sh: $bin not built (bash scripts/build.sh)" >&2; exit 1; }
[[ -z $baseline || -x $baseline ]] || { echo "bench_dense_map.sh: --baseline $baseline is not an executable" >&2; exit 1; }
[[ $steps =~ ^[0-9]+$ ]] || { echo "bench_dense_map.sh: --steps must be a number, got '$steps'" >&2; exit 1; }
mkdir -p "$out"

# config FILE BASE OVERRIDES_JSON: BASE (a config YAML, or "" for none) with the nerf overrides merged in.
config() {
  /usr/bin/python3 - "$1" "$2" "$3" "$steps" <<'PY'
import json, sys, yaml
path, base, over, steps = sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), int(sys.argv[4])
cfg = yaml.safe_load(open(base)) if base else {}
nerf = cfg.setdefault("nerf", {})
nerf.update(over)
nerf.setdefault("outputs", {})["flythrough_frames"] = 0  # no effect on the figures; saves its 30 s
if steps > 0:
    nerf["final_train_steps"] = steps
yaml.safe_dump(cfg, open(path, "w"), sort_keys=False)
PY
}

# run SEQ BUILD_NAME BINARY: one whole run; its report.json lands in $out/SEQ-BUILD_NAME.
run() {
  local seq=$1 name=$2 exe=$3 dir=$out/$1-$2 cfg=$out/$1.yaml t0
  local args=()
  case $seq in
    kitti) args=(--dataset "kitti:$data/kitti06_first51"); config "$cfg" "$root/config/system/kitti.yaml" '{"holdout_every": 5}' ;;
    tsukuba) args=(--dataset "tsukuba:$data/new_tsukuba_150"); config "$cfg" "$root/config/system/video.yaml" '{"holdout_every": 5}' ;;
    temple) args=(--dataset "middlebury:$data/middlebury_templeRing"); config "$cfg" "$root/config/system/photos.yaml" '{}' ;;
    fountain) args=(--dataset "strecha:$data/strecha_fountain-P11"); config "$cfg" "$root/config/system/photos.yaml" '{"holdout_every": 4, "downscale": 4}' ;;
    room) args=(--dataset "$out/room_sequence"); config "$cfg" "$root/config/system/synthetic.yaml" '{}' ;;
    demo) args=(--demo-frames 300); config "$cfg" "" '{}' ;;
  esac
  rm -rf "$dir"
  t0=$(date +%s)
  if ! "$exe" run "${args[@]}" --config "$cfg" --out "$dir" >"$dir.log" 2>&1; then
    echo "  $seq ($name): the run failed; see $dir.log" >&2
  fi
  echo "$(( $(date +%s) - t0 ))" >"$dir.seconds"
}

available() {
  case $1 in
    kitti) [[ -d $data/kitti06_first51 ]] ;;
    tsukuba) [[ -d $data/new_tsukuba_150 ]] ;;
    temple) [[ -d $data/middlebury_templeRing ]] ;;
    fountain) [[ -d $data/strecha_fountain-P11 ]] ;;
    room | demo) true ;;
    *) echo "bench_dense_map.sh: unknown sequence '$1'" >&2; exit 2 ;;
  esac
}

echo "bench_dense_map.sh: $(git -C "$root" rev-parse --short HEAD) ${baseline:+against $baseline }on $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg), $( ((steps > 0)) && echo "$steps final steps" || echo "60 s of final training")"
for seq in $only; do
  if ! available "$seq"; then
    echo "  $seq: skipped, its data is not in $data"
    continue
  fi
  if [[ $seq == room && ! -f $out/room_sequence/groundtruth.txt ]]; then
    "$bin" synth --scene room --frames 600 --out "$out/room_sequence" >"$out/room_synth.log" 2>&1
  fi
  [[ -n $baseline ]] && run "$seq" baseline "$baseline"
  run "$seq" current "$bin"
done

/usr/bin/python3 - "$out" $only <<'PY'
import json, os, sys
out, seqs = sys.argv[1], sys.argv[2:]
def fmt(v, f):
    return f.format(v) if isinstance(v, (int, float)) else "-"
print("| sequence | build | held-out PSNR (dB) | SSIM | depth vs map points | depth vs ground truth | final steps | views | seconds |")
print("|---|---|---|---|---|---|---|---|---|")
for seq in seqs:
    for name in ("baseline", "current"):
        d = os.path.join(out, f"{seq}-{name}")
        if not os.path.exists(d + ".seconds"):
            continue
        try:
            r = json.load(open(os.path.join(d, "report.json")))
        except (OSError, ValueError):
            print(f"| {seq} | {name} | no report.json ({d}.log) | | | | | | |")
            continue
        # Synthetic sequences score the frames between keyframes (nerf_psnr_heldout) and have depth
        # ground truth (nerf_depth_median_abs_rel).
        print(f"| {seq} | {name} | {fmt(r.get('nerf_psnr_heldout'), '{:.2f}')} | {fmt(r.get('nerf_ssim_heldout'), '{:.3f}')}"
              f" | {fmt(r.get('nerf_depth_vs_points_heldout'), '{:.1%}')} | {fmt(r.get('nerf_depth_median_abs_rel'), '{:.1%}')}"
              f" | {fmt(r.get('nerf_final_train_steps'), '{}')} | {fmt(r.get('nerf_views'), '{}')} | {open(d + '.seconds').read().strip()} |")
PY
