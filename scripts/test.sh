#!/usr/bin/env bash
# The README's second command: installs everything, builds, and runs the whole test suite.
# Tests that need ../shared/data skip when it is absent; NERFSLAM_REQUIRE_DATA=1 turns that into a
# failure (CI sets it). NERFSLAM_DATA_DIR points elsewhere.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
bash scripts/build.sh
build=${BUILD_DIR:-build}
ctest --test-dir "$build" --output-on-failure --parallel "$(nproc)" --timeout 900 "$@"
