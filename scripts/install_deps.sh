#!/usr/bin/env bash
# Installs every Debian 12 package nerfslam needs to build, run and test (library, CLI, ROS 1 layer,
# tests, benchmarks, fuzzing). Idempotent: packages already present are left alone.
# Usage: scripts/install_deps.sh [--no-ros]
set -euo pipefail

with_ros=1
for a in "$@"; do
  case "$a" in
    --no-ros) with_ros=0 ;;
    -h|--help) sed -n '2,4p' "$0"; exit 0 ;;
    *) echo "install_deps.sh: unknown option '$a' (valid: --no-ros)" >&2; exit 2 ;;
  esac
done

BUILD_PKGS=(
  build-essential cmake ninja-build pkg-config git clang-format clang-tidy ccache
  libeigen3-dev libopencv-dev libjpeg-dev zlib1g-dev libceres-dev libpcl-dev
  libosmesa6-dev libhwy-dev liboctomap-dev
  libcli11-dev libyaml-cpp-dev libspdlog-dev libfmt-dev nlohmann-json3-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  clang libclang-rt-14-dev python3-yaml
)
ROS_PKGS=(
  catkin ros-core-dev libroscpp-dev libtf2-ros-dev libtf2-geometry-msgs-dev libimage-transport-dev
  libcv-bridge-dev libpcl-conversions-dev libpcl-ros-dev ros-message-generation ros-message-runtime
  libstd-srvs-dev libnav-msgs-dev libsensor-msgs-dev libvisualization-msgs-dev libgeometry-msgs-dev
  libstd-msgs-dev libdiagnostic-updater-dev python3-rostest librostest-dev python3-roslaunch rviz xvfb
  python3-gencpp python3-genmsg python3-genpy
  python3-rostopic python3-sensor-msgs python3-geometry-msgs python3-nav-msgs python3-visualization-msgs python3-tf2-msgs
  rosbash
  librosbag-storage-dev libtf2-msgs-dev
)

pkgs=("${BUILD_PKGS[@]}")
[ "$with_ros" = 1 ] && pkgs+=("${ROS_PKGS[@]}")

if [ "$(id -u)" = 0 ]; then
  SUDO=()
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
  SUDO=(sudo -n)
else
  echo "install_deps.sh: installing Debian packages needs root. Run as root, or as a user with" >&2
  echo "passwordless sudo, or ask an administrator to run:" >&2
  echo "  apt-get install --no-install-recommends ${pkgs[*]}" >&2
  exit 1
fi

missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -eq 0 ]; then
  echo "install_deps.sh: all ${#pkgs[@]} packages already installed."
  exit 0
fi
echo "install_deps.sh: installing ${#missing[@]} package(s): ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${SUDO[@]}" apt-get update -qq
"${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "install_deps.sh: done."
