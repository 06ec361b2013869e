#!/usr/bin/env bash
# Builds the libFuzzer targets (clang, ASan+UBSan) in build-fuzz and runs each for a while.
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]    # default 60 s, all targets
#   scripts/fuzz.sh 10                                  # CI-sized smoke run
#   scripts/fuzz.sh 600 fuzz_trajectory                 # long run of one target
#
# Seed corpora are assembled from the real shared data ($NERFSLAM_DATA_DIR, default ../shared/data)
# under build-fuzz/fuzz-seeds/<target>; what the fuzzer learns goes to build-fuzz/fuzz-corpus/<target>
# (kept between runs), reproducers of findings to build-fuzz/fuzz-artifacts/<target>/. Nothing is
# written into the source tree. Targets run one after another (the machine is shared). Exits non-zero
# when any target reports a finding (crash, sanitizer report, leak, uncaught exception, timeout,
# out-of-memory) or fails to build. See docs/fuzzing.md.
set -euo pipefail

SECS=${1:-60}
[[ $# -gt 0 ]] && shift
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
BUILD=${NERFSLAM_FUZZ_BUILD_DIR:-$ROOT/build-fuzz}
DATA=${NERFSLAM_DATA_DIR:-$ROOT/../shared/data}
JOBS=${NERFSLAM_FUZZ_BUILD_JOBS:-2}
SEP=$'\n~~~~\n'   # section separator of multi-file inputs (test/fuzz/fuzz_common.h)

ALL=(fuzz_trajectory fuzz_camera_yaml fuzz_options_yaml fuzz_image fuzz_ply
     fuzz_dataset_tum fuzz_dataset_euroc fuzz_dataset_kitti fuzz_dataset_transforms
     fuzz_dataset_middlebury fuzz_dataset_strecha fuzz_dataset_tsukuba fuzz_dataset_folder fuzz_model)
if [[ $# -gt 0 ]]; then TARGETS=("$@"); else TARGETS=("${ALL[@]}"); fi
[[ -d $DATA ]] || { echo "fuzz.sh: shared data not found at $DATA (set NERFSLAM_DATA_DIR)" >&2; exit 2; }

# ---- build ----
if [[ ! -f $BUILD/build.ninja ]]; then
  CC=clang CXX=clang++ cmake -S "$ROOT" -B "$BUILD" -G Ninja -DNERFSLAM_BUILD_FUZZERS=ON \
    -DNERFSLAM_SANITIZE="address;undefined" -DNERFSLAM_BUILD_ROS=OFF -DNERFSLAM_BUILD_TESTS=OFF \
    -DNERFSLAM_BUILD_BENCHMARKS=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo
fi
build=("${TARGETS[@]}" fuzz_make_image_seeds)
for t in "${TARGETS[@]}"; do if [[ $t == fuzz_model ]]; then build+=(fuzz_make_model_seed); fi; done
ninja -C "$BUILD" -j"$JOBS" "${build[@]}"

# LeakSanitizer cannot run where ptrace is forbidden or in use (some containers and sandboxes): it
# then fails every ASan program at exit. That is the environment, not a finding: probe once, and
# if so, run without leak detection and say so in the summary.
leaks=""
probe=$("$BUILD/test/fuzz/${TARGETS[0]}" -runs=0 2>&1 </dev/null || true)
if grep -q 'LeakSanitizer has encountered a fatal error' <<<"$probe"; then
  echo "fuzz.sh: LeakSanitizer cannot run in this environment; fuzzing without leak detection:"
  grep -m 2 'HINT' <<<"$probe" || true
  export ASAN_OPTIONS=${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0
  leaks=", no leak detection (unavailable here)"
fi

# ---- seed corpora from the real data ----
SEEDS=$BUILD/fuzz-seeds
rm -rf "$SEEDS"
# seed TARGET NAME PART... : writes one input whose sections are the PARTs, joined by $SEP.
# A PART is FILE (whole), FILE:N (first N lines) or =TEXT (literal text).
seed() {
  local target=$1 name=$2; shift 2
  mkdir -p "$SEEDS/$target"
  local out=$SEEDS/$target/$name first=1 part
  : >"$out"
  for part in "$@"; do
    [[ $first == 1 ]] || printf '%s' "$SEP" >>"$out"
    first=0
    case $part in
      =*) printf '%s' "${part#=}" >>"$out" ;;
      *:[0-9]*) head -n "${part##*:}" "${part%:*}" >>"$out" ;;
      *) cat "$part" >>"$out" ;;
    esac
  done
}
EVO=$DATA/evo_reference
KIT=$DATA/kitti06_first51
EUR=$DATA/euroc_V1_01_piece
CAM=$ROOT/config/camera

for f in "$EVO"/*.txt; do seed fuzz_trajectory "$(basename "$f")" "$f:60"; done
seed fuzz_trajectory kitti00_with_times "$EVO/KITTI_00_gt.txt:40" "$EVO/KITTI_00_gt_times.txt:40"
seed fuzz_trajectory kitti06_with_times "$KIT/poses.txt" "$KIT/times.txt"
seed fuzz_trajectory euroc_csv "$EVO/V102_groundtruth.csv:40"
seed fuzz_trajectory euroc_body_tum "$EUR/groundtruth_body_tum.txt:40"
seed fuzz_trajectory tsukuba_traj "$DATA/new_tsukuba_150/cam_traj_truth.txt:20"
seed fuzz_trajectory euroc_stamp_over_19_digits "=123456789012345678901234567890,1,2,3,1,0,0,0"   # a past finding

for f in "$CAM"/*.yaml "$EUR/mav0/cam0/sensor.yaml"; do seed fuzz_camera_yaml "$(basename "$f")" "$f"; done
seed fuzz_camera_yaml ros_camera_info '=image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [517.3, 0, 318.6, 0, 516.5, 255.3, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.262, -0.953, -0.0054, 0.0026, 1.163]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [517.3, 0, 318.6, 0, 0, 516.5, 255.3, 0, 0, 0, 1, 0]
'

for f in "$ROOT"/config/system/*.yaml; do if [[ -f $f ]]; then seed fuzz_options_yaml "$(basename "$f")" "$f"; fi; done
seed fuzz_options_yaml all_types '=core:
  threads: 2
  log_level: debug
  seed: 7
eval:
  max_dt: 0.01
  align: sim3
leaf:
  flag: true
  count: 5
  big: 12345678901
  ratio: 0.25
  scale: 1e-3
  mode: b
  weights: [0.5, 1.5, -2]
  sizes: [1, 2, 3]
outer:
  x: .inf
  inner: {flag: false, mode: "a", sizes: []}
'

# PLY headers: a binary cloud as PCL writes it, the sparse map's ASCII cloud, a binary mesh.
seed fuzz_ply binary_cloud "=ply
format binary_little_endian 1.0
comment PCL generated
element vertex 2
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element camera 1
property float view_px
end_header
$(printf 'xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx')"
seed fuzz_ply ascii_map "=ply
format ascii 1.0
comment nerfslam sparse map (world frame, map units)
element vertex 2
property double x
property double y
property double z
property int observations
end_header
1 2 3 4
5 6 7 8
"
seed fuzz_ply binary_mesh "=ply
format binary_big_endian 1.0
element vertex 3
property float x
property float y
property float z
element face 1
property list uchar int vertex_indices
end_header
$(printf '%049d' 0)"

# readImage: the first byte picks extension and mode (test/fuzz/fuzz_image.cpp).
img_seed() { mkdir -p "$SEEDS/fuzz_image"; { printf "\\x$(printf %02x "$2")"; cat "$3"; } >"$SEEDS/fuzz_image/$1"; }
img_seed chessboard_jpg_gray 1 "$DATA/opencv_chessboard/left01.jpg"
img_seed chessboard_jpg_unchanged 13 "$DATA/opencv_chessboard/left02.jpg"
img_seed kitti_png_gray 0 "$(ls "$KIT"/image_l/* | head -n 1)"
img_seed euroc_png_color 6 "$(ls "$EUR"/mav0/cam0/data/* | head -n 1)"
img_seed lego_rgba_unchanged 12 "$DATA/lego_train/train/r_0.png"
# Small crops of real images in every format and depth: fast to decode, so the fuzzer mutates them.
"$BUILD/test/fuzz/fuzz_make_image_seeds" "$SEEDS/fuzz_image" "$DATA/opencv_chessboard/left01.jpg" \
  "$(ls "$KIT"/image_l/* | head -n 1)" "$DATA/lego_train/train/r_0.png" "$DATA/middlebury_templeRing/templeR0013.png"

fr1=$EVO/freiburg1_xyz-groundtruth.txt
rgb=$'# color images\n# timestamp filename\n'
i=0
while read -r ts _; do rgb+="$ts rgb/$i.png"$'\n'; i=$((i + 1)); done < <(grep -v '^#' "$fr1" | awk 'NR % 3 == 1' | head -n 10)
seed fuzz_dataset_tum full "=$rgb" "$fr1:60" "$CAM/tum_fr1.yaml"
seed fuzz_dataset_tum preset_camera "=$rgb" "$fr1:60"
seed fuzz_dataset_tum no_groundtruth "=$rgb"

seed fuzz_dataset_euroc tum_gt "$EUR/mav0/cam0/data.csv" "$EUR/mav0/cam0/sensor.yaml" "$EUR/groundtruth_body_tum.txt"
seed fuzz_dataset_euroc csv_gt "$EUR/mav0/cam0/data.csv:20" "$EUR/mav0/cam0/sensor.yaml" "=" "$EVO/V101_gt.txt:5"
seed fuzz_dataset_euroc no_gt "$EUR/mav0/cam0/data.csv:10" "$EUR/mav0/cam0/sensor.yaml"

seed fuzz_dataset_kitti full "$KIT/times.txt" "$KIT/calib.txt" "$KIT/poses.txt"
seed fuzz_dataset_kitti no_poses "$KIT/times.txt:10" "$KIT/calib.txt"

seed fuzz_dataset_transforms lego "$DATA/lego_train/transforms_train.json"

seed fuzz_dataset_middlebury templeRing "$DATA/middlebury_templeRing/templeR_par.txt"
seed fuzz_dataset_middlebury dino_par_foreign_names "$DATA/middlebury_dino/dino_par.txt:10"

cams=("$DATA"/strecha_fountain-P11/gt_dense_cameras/*.camera)
seed fuzz_dataset_strecha all "${cams[@]}"
seed fuzz_dataset_strecha first_three "${cams[@]:0:3}"

seed fuzz_dataset_tsukuba full "$DATA/new_tsukuba_150/cam_traj_truth.txt" "$DATA/new_tsukuba_150/intrinsics.txt"
seed fuzz_dataset_tsukuba no_intrinsics "$DATA/new_tsukuba_150/cam_traj_truth.txt:30"

times=""
for n in $(seq 0 12); do times+="$(awk -v n="$n" 'BEGIN { printf "%.6f", n / 15 }')"$'\n'; done
seed fuzz_dataset_folder times_and_camera "=$times" "$CAM/tum_fr1.yaml"
seed fuzz_dataset_folder times_only "=$times"

for t in "${TARGETS[@]}"; do
  if [[ $t == fuzz_model ]]; then
    mkdir -p "$SEEDS/fuzz_model"
    # A whole model is > 8 MB (the occupancy grid is 128^3 floats per cascade) and takes seconds to
    # load under ASan, so the seeds are the real files cut after the JSON header plus 256 bytes of
    # the arrays: the fuzzer works on the header and the array bookkeeping (truncation is detected
    # after them). fuzz_model rewrites the trailing CRC.
    for opt in "" --optimizer; do
      full=$BUILD/fuzz-seeds/model$opt.nerf
      "$BUILD/test/fuzz/fuzz_make_model_seed" "$full" $opt
      hlen=$(od -An -t u8 -j 16 -N 8 "$full" | tr -d ' ')
      head -c $((24 + hlen + 256)) "$full" >"$SEEDS/fuzz_model/header$opt"
      rm -f "$full"
    done
  fi
done

# ---- run ----
# UBSan reports are findings too: stop at the first one (recoverable checks would only print).
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
status=0
summary=()
# fuzz TARGET [FLAG...]: one libFuzzer run of TARGET into $log; sets rc, runs, secs, cov.
fuzz() {
  local t=$1
  shift
  rc=0
  "$BUILD/test/fuzz/$t" "$corpus" "$SEEDS/$t" -max_total_time="$SECS" -timeout=10 -rss_limit_mb=2048 \
    -artifact_prefix="$artifacts/" -print_final_stats=1 "$@" >"$log" 2>&1 || rc=$?
  runs=$(sed -n 's/^Done \([0-9]*\) runs in \([0-9]*\) second.*/\1/p' "$log" | tail -n 1)
  secs=$(sed -n 's/^Done \([0-9]*\) runs in \([0-9]*\) second.*/\2/p' "$log" | tail -n 1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -n 1 || true)
}
for t in "${TARGETS[@]}"; do
  corpus=$BUILD/fuzz-corpus/$t
  artifacts=$BUILD/fuzz-artifacts/$t
  log=$BUILD/fuzz-logs/$t.log
  mkdir -p "$corpus" "$artifacts" "$(dirname "$log")" "$SEEDS/$t"
  echo "=== $t: ${SECS}s (log $log)"
  fuzz "$t" ${leaks:+-detect_leaks=0}
  if [[ $rc -ne 0 ]]; then
    status=1
    summary+=("$t: FINDING (exit $rc) - reproducer(s): $(ls "$artifacts" | tr '\n' ' ')")
    grep -m 1 -E 'ERROR: (AddressSanitizer|LeakSanitizer|libFuzzer)|runtime error:|uncaught exception|SUMMARY' "$log" || true
    # The finding's own report (CI keeps only the log's tail; the build directory may be gone).
    echo "--- the end of $log:"
    tail -n 30 "$log"
    echo "---"
  else
    rate=$(( ${runs:-0} / (${secs:-1} > 0 ? ${secs:-1} : 1) ))
    summary+=("$t: ok, ${runs:-?} runs in ${secs:-?} s (${rate} exec/s), ${cov:-cov ?}, corpus $(ls "$corpus" | wc -l) files$leaks")
  fi
done
echo "=== summary"
printf '%s\n' "${summary[@]}"
exit $status
