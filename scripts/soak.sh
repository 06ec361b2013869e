#!/usr/bin/env bash
# Soak run of the standalone runner: the whole system (tracking, mapping, NeRF) on a long synthetic
# sequence, then a check that memory stays bounded and tracking does not slow down as the map grows.
#
#   scripts/soak.sh [FRAMES] [OUT]     # default 10000 frames into out/soak-FRAMES (the documented long run)
#   scripts/soak.sh 1200 /tmp/soak     # the CI-sized run
#
# `nerfslam run --demo-frames FRAMES` renders the synthetic room (handheld walk, 30 fps) into OUT/sequence
# and runs on it. Its report.json gives, per 200-frame window, the tracking thread's CPU time per frame
# and the process's resident memory and map size at the window's end (tracking_ms_windows). After a
# warm-up (the first 30 % of the windows, at least 2), the check fails when
#   - resident memory at the end exceeds the largest value seen by the end of the warm-up by more
#     than NERFSLAM_SOAK_RSS_GROWTH (default 0.05: 5 %) or
#   - the median tracking CPU time of the last third of the windows exceeds that of the windows
#     right after the warm-up by more than NERFSLAM_SOAK_SLOWDOWN (default 0.15: 15 %),
# or when tracking was lost for good (less than 95 % of the frames tracked).
# Needs a built tree (scripts/build.sh); NERFSLAM_BUILD_DIR overrides `build`. Extra `run` options can
# be given in NERFSLAM_SOAK_ARGS (e.g. "--no-nerf"). The rendered sequence is deleted afterwards
# (10,000 frames are ~6 GB); NERFSLAM_SOAK_KEEP=1 keeps it.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
frames=${1:-10000}
out=${2:-$root/out/soak-$frames}
bin=${NERFSLAM_BUILD_DIR:-$root/build}/nerfslam
[[ -x $bin ]] || { echo "soak.sh: $bin not found: build first (scripts/build.sh)" >&2; exit 2; }
[[ $frames =~ ^[0-9]+$ && $frames -ge 1000 ]] || { echo "soak.sh: FRAMES must be a number >= 1000 (got '$frames')" >&2; exit 2; }

rm -rf "$out"
mkdir -p "$out"
echo "soak.sh: nerfslam run --demo-frames $frames ${NERFSLAM_SOAK_ARGS:-} --out $out"
start=$(date +%s)
rc=0
# shellcheck disable=SC2086
"$bin" run --demo-frames "$frames" ${NERFSLAM_SOAK_ARGS:-} --out "$out" >"$out/run.log" 2>&1 || rc=$?
echo "soak.sh: run finished in $(( $(date +%s) - start )) s, exit code $rc (log: $out/run.log)"
[[ ${NERFSLAM_SOAK_KEEP:-0} == 1 ]] || rm -rf "$out/sequence"
if [[ $rc != 0 ]]; then tail -n 30 "$out/run.log" >&2; exit 1; fi

/usr/bin/python3 - "$out/report.json" "${NERFSLAM_SOAK_RSS_GROWTH:-0.05}" "${NERFSLAM_SOAK_SLOWDOWN:-0.15}" <<'EOF'
import json, statistics, sys
rep = json.load(open(sys.argv[1]))
max_growth, max_slowdown = float(sys.argv[2]), float(sys.argv[3])
w = [x for x in rep["tracking_ms_windows"] if "rss_mb" in x]
if len(w) < 5:
    sys.exit(f"soak.sh: {sys.argv[1]}: only {len(w)} full windows with memory samples (need >= 5)")
print(f"{'frames':>12} {'cpu ms med':>10} {'p99':>7} {'wall med':>8} {'RSS MB':>8} {'keyframes':>9} {'points':>7}")
for x in w:
    a = x["first_frame"]
    print(f"{a:>5}-{a + x['frames'] - 1:<6} {x['cpu_ms_median']:>10.2f} {x['cpu_ms_p99']:>7.2f} "
          f"{x['wall_ms_median']:>8.2f} {x['rss_mb']:>8.1f} {x['keyframes']:>9} {x['map_points']:>7}")
warm = max(2, round(0.3 * len(w)))
rss_warm = max(x["rss_mb"] for x in w[:warm])
rss_end, rss_max = w[-1]["rss_mb"], max(x["rss_mb"] for x in w)
growth = rss_end / rss_warm - 1
third = max(1, len(w) // 3)
early = statistics.median(x["cpu_ms_median"] for x in w[warm:warm + third])
late = statistics.median(x["cpu_ms_median"] for x in w[-third:])
slowdown = late / early - 1
tracked = rep["frames_tracked"] / rep["frames"]
print(f"frames tracked {rep['frames_tracked']}/{rep['frames']} ({100 * tracked:.1f} %), keyframes {rep['keyframes']}, "
      f"map points {rep['map_points']}, peak RSS {rep['peak_rss_mb']:.0f} MB, wall {rep['wall_time_s']:.0f} s")
print(f"RSS: {rss_warm:.0f} MB by the end of the warm-up (frame {w[warm - 1]['first_frame'] + 200}), "
      f"{rss_end:.0f} MB at the end, max {rss_max:.0f} MB: growth {100 * growth:+.1f} % (limit {100 * max_growth:.0f} %)")
dkf = w[-1]["keyframes"] - w[warm - 1]["keyframes"]
dpts = w[-1]["map_points"] - w[warm - 1]["map_points"]
print(f"map after the warm-up: {dkf:+d} keyframes, {dpts:+d} points"
      + (f"; {(w[-1]['rss_mb'] - w[warm - 1]['rss_mb']) / dkf:.2f} MB of RSS per keyframe added" if dkf > 0 else ""))
print(f"tracking CPU per frame, median of window medians: {early:.2f} ms after the warm-up, {late:.2f} ms in the "
      f"last third: {100 * slowdown:+.1f} % (limit {100 * max_slowdown:.0f} %)")
if "ate_percent_of_path" in rep:
    print(f"ATE {rep['ate_percent_of_path']:.3f} % of path")
bad = []
if growth > max_growth: bad.append("memory grew after the warm-up")
if slowdown > max_slowdown: bad.append("tracking slowed down")
if tracked < 0.95: bad.append("less than 95 % of the frames tracked")
if bad:
    sys.exit("soak.sh: FAILED: " + "; ".join(bad))
print("soak.sh: passed")
EOF
