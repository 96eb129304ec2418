#!/usr/bin/env bash
# Installs the Debian 12 packages proden builds and tests with; does nothing when all are present.
# Usage: tools/install-deps.sh [extra-package...]
set -euo pipefail

packages=(
  cmake g++ make pkg-config
  clang libclang-rt-14-dev                                  # make fuzz, make fuzz-smoke (libFuzzer)
  libopenimageio-dev openimageio-tools libopencv-core-dev   # OIIO's CMake target names opencv4 headers
  libopenexr-dev libimath-dev
  libboost-dev libboost-system-dev
  nlohmann-json3-dev libspdlog-dev libfmt-dev catch2 libcli11-dev libtbb-dev
  python3 curl                                              # service tests, make run
  libbenchmark-dev libopenblas-dev python3-matplotlib       # make bench (micro, sgemm, plots)
  blender python3-torch python3-numpy python3-openimageio   # learned mixer: data, training, tests
  "$@"
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "install-deps: installing ${missing[*]}" >&2
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: not root and no sudo; install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends -o DPkg::Lock::Timeout=600 "${missing[@]}"
