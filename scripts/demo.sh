#!/usr/bin/env bash
# The README's first command: installs everything, builds, and runs the end-to-end demo.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
bash scripts/build.sh
out=${1:-out/demo}
./build/nerfslam run --out "$out"
