#!/usr/bin/env bash
# Builds the test suite with a sanitizer and runs it (see docs/sanitizers.md).
#
#   scripts/sanitize.sh thread  [ctest args...]   # ThreadSanitizer, build-tsan, the threaded tests
#   scripts/sanitize.sh address [ctest args...]   # AddressSanitizer + UBSan + LeakSanitizer, build-asan
#
# Release flags plus -fsanitize=... -fno-omit-frame-pointer -g1, without ROS and benchmarks. ThreadSanitizer
# builds with gcc. AddressSanitizer builds with clang and the libFuzzer targets too, so that
# scripts/fuzz.sh runs them from this build (NERFSLAM_FUZZ_BUILD_DIR=build-asan, as CI does) instead
# of compiling the libraries a second time: clang built it all in 1,008 s where gcc took 1,458 s
# without the fuzzers (docs/sanitizers.md).
# Extra arguments go to ctest after the default selection, so a -R or -E given there replaces the
# default one (e.g. `scripts/sanitize.sh thread -R '^MapStore\.'`). NERFSLAM_SANITIZE_LONG=1 runs
# the tests left to the long run too. Dependencies must be installed (scripts/install_deps.sh).
#
# Every sanitizer report goes to a file under <build>/sanitizer-logs/ (log_path), also those of
# child processes the tests start (the CLI, kill helpers) whose exit codes a test may expect to be
# non-zero anyway; the script prints them and exits non-zero when there is any, even if ctest passed.
set -euo pipefail

kind=${1:-}
[[ $# -gt 0 ]] && shift
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
supp=$root/test/sanitizers

case $kind in
  thread)
    build=${NERFSLAM_SANITIZE_BUILD_DIR:-build-tsan}
    san=thread
    compiler=()  # the default, gcc
    # The tests that run our threads: map locking, queues, the keyframe bus, the mapping, loop-closing
    # and NeRF threads, the trainer's and field's worker threads, the whole threaded system, the map store.
    select='^(Map|MapStore|MapStoreCli|MappingThread|LoopClosingMap|KeyframeBus|BoundedQueue|SyntheticSlam|TrackingFaults|NerfMapping|Trainer|TrainerOnline|RadianceField|RunSystem)\.'
    finding=()
    # Cannot work under TSan (not findings): the TSan runtime dies with SIGBUS at start-up under the
    # test's `ulimit -f 4` (it maps a /tmp/tsan.rodata.<pid> file it cannot extend); the kill test's
    # time window assumes an uninstrumented child (under TSan the kills land before the first save).
    never=('MapStore\.SaveIntoAFullDiskFailsAndKeepsThePreviousMap$' 'MapStore\.KillDuringSaveLeavesPreviousMapLoadable$')
    # Long run only (NERFSLAM_SANITIZE_LONG=1): the end-to-end runs whose TSan times (measured, one
    # run at load 6-14 on the 2-core machine, docs/sanitizers.md) would take the CI run past its
    # budget. Their threads are all in the CI selection through shorter tests: the tracking, mapping
    # and NeRF threads together (SyntheticSlam.TrackingMappingAndNerfThreadsRunTogether), the CLI
    # runner's threads (RunSystem.StrechaFountain..., RunSystem.EurocStatic...), the NeRF thread fed
    # by the keyframe bus (NerfMapping.FollowsPoses..., NeverBlocks...), the trainer's workers.
    long=('Trainer\.SyntheticSphereReachesPsnrFloor$'                                         # 230-335 s
          'NerfMapping\.(HeldOutViewsImproveWithTraining|RefitKeepsWhatWasLearned|ResumesFromASavedModelFrozenOrTraining)$'
          'NerfMapping\.(TrainsInItsThreadOnPublishedKeyframes|StartsAgainWhenTheSparseMapIsReset)$'  # 118, 80 s
          'NerfMapping\.DivergenceIsRolledBackAndTrainingGoesOn$'   # needs 150 steps in 180 s: 144 made
          'NerfMapping\.WholeSystemWritesTheDenseMapAndReport$'    # > 2400 s (timed out)
          'NerfMapping\.MeasuresItsHeldOutPsnrWhileItTrains$'      # needs 300 steps in 120 s: 30 s in Release
          'Trainer\.SparseDepthPutsTheSurfaceAtThePoints$'        # 2 x 200 steps: 6-7 s in Release
          'RunSystem\.NerfRunLeavesASurfacePreviewAFlythroughAndATrajectoryPlot$'  # 31-57 s in Release
          'MapStoreCli\.(LocalizesInASavedMapAlongAnotherTrajectory|ExtendAddsKeyframesToASavedMap)$'  # 272, 341 s
          'RunSystem\.(Kitti06First51TracksEveryFrameAccurately|NewTsukubaFirst75)$'                  # 205, 398 s
          'RunSystem\.(WithoutDatasetRunsTheSyntheticRoomDemo|MiddleburyTempleRingRegistersEveryView)$'  # 135, 61 s
          'SyntheticSlam\.(HandheldRoom|PlanarScene|PureRotation|LocalizationOnly)'   # 156-1116 s
          'TrackingFaults\.')                                   # 640x480 room sequences, like SyntheticSlam
    timeout=900
    # Only the executables those tests are in, and the CLI some of them run.
    targets=(nerfslam_cli nerfslam_test_mapping nerfslam_test_nerf nerfslam_test_system)
    ;;
  address)
    build=${NERFSLAM_SANITIZE_BUILD_DIR:-build-asan}
    san="address;undefined"
    cxx=/usr/bin/clang++
    compiler=(-DCMAKE_C_COMPILER=/usr/bin/clang -DCMAKE_CXX_COMPILER="$cxx" -DNERFSLAM_BUILD_FUZZERS=ON)
    select='.'
    finding=()
    # Not a finding: the kill test's time window assumes an uninstrumented child; under ASan a save
    # takes longer, so fewer of the 60 kills land between saves than the test asks for (11 map
    # generations against > 20). Its subject, atomic saves, is tested in the Release test stage.
    # Nor the damaged-bag test: its checking child reads damaged bags, whose overstated record lengths
    # make librosbag's deserialising read out of bounds; ASan reports it in that child (the crash the
    # child is there to take), docs/sanitizers.md.
    never=('MapStore\.KillDuringSaveLeavesPreviousMapLoadable$' 'BagDataset\.DamagedBytesAreRefusedNeverACrash$')
    # Long run only (NERFSLAM_SANITIZE_LONG=1): the end-to-end runs that take over a minute each
    # under ASan (measured, docs/sanitizers.md). The parsers, the threads, the map store, the trainer
    # and the renderer all run in the CI selection through their shorter tests.
    long=('Trainer\.SyntheticSphereReachesPsnrFloor$'  # 210 s: a quality floor; the trainer's code runs in Trainer.*, TrainerOnline.*
          'NerfMapping\.(HeldOutViewsImproveWithTraining|RefitKeepsWhatWasLearned|ResumesFromASavedModelFrozenOrTraining)$'
          'NerfMapping\.(DivergenceIsRolledBackAndTrainingGoesOn|WholeSystemWritesTheDenseMapAndReport)$'
          'NerfMapping\.MeasuresItsHeldOutPsnrWhileItTrains$'  # 300 steps in 120 s: 30 s in Release
          'RunSystem\.NerfRunLeavesASurfacePreviewAFlythroughAndATrajectoryPlot$'  # 31-57 s in Release
          'TrackingFaults\.(SuddenJumpIsLostThenRelocalisedWhenTheViewReturns|BlackFramesFrozenFrameAndGapAreReportedAndRecovered)$'
          'RunSystem\.(Kitti06First51TracksEveryFrameAccurately|NewTsukubaFirst75|WithoutDatasetRunsTheSyntheticRoomDemo)$'
          'MapStoreCli\.(ExtendAddsKeyframesToASavedMap|LocalizesInASavedMapAlongAnotherTrajectory)$'
          'SyntheticSlam\.(LocalizationOnlySwitchStopsAndResumesMapping|HandheldRoomTracksEveryFrameAccurately)$'
          'OdometryScale\.(SyntheticRoomIsMetricAfterTenSeconds|Kitti06WithNoisyOdometryIsMetric)$'  # 17, 7 s in Release
          'VideoRun\.LosslessVideoTracksExactlyLikeItsFrames$'  # 12 s in Release: two 640x480 room runs
          'BagRun\.'  # 10 s each in Release: two room runs, two KITTI 06 runs
          'LoopClosing\.RoomTwoLapsEveryRevisitClosedAndAteCutByThree$'  # 49 s in Release at load 6.6: two runs
          'TrainCli\.DepthImagesSuperviseTheTrainingViews$'  # 24 s in Release: a synthetic room, two trainings
          'RunStop\.' 'TrainStop\.'  # signals timed for Release speed on whole KITTI / lego runs
          # 85-99 s each under ASan (2026-12-07); their code runs in Distill.IsDeterministic...,
          # PoseRefine.DivergedCorrection..., LineOfSight.* and Trainer.SurfacePoints..., and every
          # writer in the tests of its own output (the kills are the Release stage's).
          'Distill\.StudentReproducesTheTeacherInsideItsCube$' 'PoseRefine\.PerturbedViewConvergesBackOnTheSphere$'
          'Trainer\.SparseDepthPutsTheSurfaceAtThePoints$' 'OutputKill\.EveryWriterSurvivesSigkill$')
    timeout=1800
    targets=(all)
    ;;
  *)
    echo "usage: scripts/sanitize.sh thread|address [ctest args...]" >&2
    exit 2
    ;;
esac
# -O1 (NERFSLAM_SANITIZE_OPT) by default: the instrumented build is what a CI run pays for most
# (docs/sanitizers.md has the measured build and test times).
opt=${NERFSLAM_SANITIZE_OPT:--O1}
exclude=("${finding[@]}" "${never[@]}")
# The long run also gets a longer per-test timeout: its end-to-end tests take up to ~20 min each.
if [[ ${NERFSLAM_SANITIZE_LONG:-0} == 1 ]]; then timeout=3600; else exclude+=("${long[@]}"); fi
ctest_select=(-R "$select")
if [[ ${#exclude[@]} -gt 0 ]]; then ctest_select+=(-E "^($(IFS='|'; echo "${exclude[*]}"))"); fi

# pyenv's python3 can come first on PATH and breaks catkin's CMake: use Debian's (as scripts/build.sh).
export PATH=/usr/bin:$PATH
gen=()
command -v ninja >/dev/null 2>&1 && gen=(-G Ninja)
# A build folder made with another generator or compiler is made again (CMake cannot switch them).
if [ -f "$build/CMakeCache.txt" ] && { ! grep -q "CMAKE_GENERATOR:INTERNAL=${gen[1]:-Unix Makefiles}" "$build/CMakeCache.txt" ||
  { [[ -n ${cxx:-} ]] && ! grep -qx "CMAKE_CXX_COMPILER:FILEPATH=$cxx" "$build/CMakeCache.txt"; }; }; then
  rm -rf "$build"
fi

TIMEFORMAT="sanitize.sh $kind: %0R s wall, %0U s user + %0S s system CPU"
echo "sanitize.sh $kind: configure and build $build"
time {
  cmake -S . -B "$build" "${gen[@]}" "${compiler[@]}" -DCMAKE_BUILD_TYPE=Release -DNERFSLAM_SANITIZE="$san" \
    -DCMAKE_CXX_FLAGS_RELEASE="$opt -DNDEBUG" -DCMAKE_C_FLAGS_RELEASE="$opt -DNDEBUG" \
    -DNERFSLAM_BUILD_ROS=OFF -DNERFSLAM_BUILD_BENCHMARKS=OFF -DNERFSLAM_BUILD_TESTS=ON -DNERFSLAM_TEST_TIMEOUT="$timeout" \
    -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3
  cmake --build "$build" --parallel "$(nproc)" --target "${targets[@]}"
}

logs=$(cd "$build" && pwd)/sanitizer-logs
rm -rf "$logs"
mkdir -p "$logs"
# Suppressions (test/sanitizers/*.supp) are only for reports inside uninstrumented system libraries.
common="log_path=$logs/$kind:print_suppressions=0"
if [[ $kind == thread ]]; then
  export TSAN_OPTIONS="$common:halt_on_error=1:second_deadlock_stack=1:suppressions=$supp/tsan.supp${TSAN_OPTIONS:+:$TSAN_OPTIONS}"
else
  export ASAN_OPTIONS="$common:detect_leaks=1:halt_on_error=1:check_initialization_order=1:strict_init_order=1${ASAN_OPTIONS:+:$ASAN_OPTIONS}"
  [[ -f $supp/lsan.supp ]] && export LSAN_OPTIONS="suppressions=$supp/lsan.supp${LSAN_OPTIONS:+:$LSAN_OPTIONS}"
  export UBSAN_OPTIONS="$common:halt_on_error=1:print_stacktrace=1${UBSAN_OPTIONS:+:$UBSAN_OPTIONS}"
fi

echo "sanitize.sh $kind: ctest ${ctest_select[*]} $*"
rc=0
time { ctest --test-dir "$build" --output-on-failure --no-tests=error --parallel "$(nproc)" "${ctest_select[@]}" "$@" || rc=$?; }

reports=("$logs"/*)
if [[ -e ${reports[0]} ]]; then
  echo "sanitize.sh $kind: ${#reports[@]} sanitizer report file(s) in $logs (reports of child processes too):"
  for f in "${reports[@]}"; do
    echo "----- $f"
    cat "$f"
  done
  rc=1
fi
echo "sanitize.sh $kind: $([[ $rc == 0 ]] && echo 'passed, no sanitizer reports' || echo "FAILED (ctest or sanitizer reports)")"
exit $rc
