#!/usr/bin/env bash
# Installs the Debian dependencies (scripts/install_deps.sh) and builds nerfslam in ./build (Release).
# Usage: scripts/build.sh [extra cmake arguments...]   (BUILD_DIR overrides ./build)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
bash scripts/install_deps.sh ${NERFSLAM_INSTALL_ARGS:-}
build=${BUILD_DIR:-build}
# pyenv's python3 can come first on PATH and breaks catkin's CMake: use Debian's.
export PATH=/usr/bin:$PATH
gen=()
command -v ninja >/dev/null 2>&1 && gen=(-G Ninja)
if [ -f "$build/CMakeCache.txt" ] && ! grep -q "CMAKE_GENERATOR:INTERNAL=${gen[1]:-Unix Makefiles}" "$build/CMakeCache.txt"; then
  rm -rf "$build"
fi
cmake -S . -B "$build" "${gen[@]}" -DCMAKE_BUILD_TYPE=Release \
  -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 "$@"
cmake --build "$build" --parallel "$(nproc)"
