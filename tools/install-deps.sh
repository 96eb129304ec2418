#!/usr/bin/env bash
# Installs the Debian 12 packages proden builds and tests with, and the dashboard's npm packages
# (web/, exactly as web/package-lock.json pins them); does nothing when all are present.
# Usage: tools/install-deps.sh [extra-package...]
set -euo pipefail

packages=(
  cmake ninja-build g++ make pkg-config
  clang libclang-rt-14-dev                                  # make fuzz, make fuzz-smoke (libFuzzer)
  libopenimageio-dev openimageio-tools libopencv-core-dev   # OIIO's CMake target names opencv4 headers
  libopenexr-dev libimath-dev libdeflate-dev               # libdeflate: EXR ZIP chunks (io/src/exr_chunks.cpp)
  libboost-dev libboost-system-dev                          # Beast (daemon), Math (t-test quantiles)
  nlohmann-json3-dev libspdlog-dev libfmt-dev catch2 libcli11-dev libtbb-dev
  libxxhash-dev                                             # state checksums (XXH3)
  python3 curl                                              # service tests, make run
  libbenchmark-dev libopenblas-dev python3-matplotlib       # make bench (micro, sgemm, plots)
  blender python3-torch python3-numpy python3-openimageio   # learned mixer: data, training, tests
  povray povray-includes                                    # POV-Ray samples and their tests
  slurm-wlm munge                                           # Slurm end-to-end test (own cluster)
  nodejs                                                    # Flamenco job type test harness
  chromium                                                  # dashboard browser tests (playwright-core)
  "$@"
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
# The dashboard's packages (Vite, TypeScript, uPlot, Vitest, playwright-core: no browser download;
# the tests drive Debian's chromium). Node.js >= 20.19 is the machine's own (Debian 12 has 18).
web_deps() {
  local web
  web="$(dirname "$0")/../web"
  [ -f "$web/node_modules/.package-lock.json" ] && [ "$web/node_modules/.package-lock.json" -nt "$web/package-lock.json" ] && return 0
  if ! command -v node >/dev/null || ! node -e 'const [a,b]=process.versions.node.split(".").map(Number); process.exit(a>20||(a==20&&b>=19)?0:1)'; then
    echo "install-deps: the dashboard needs Node.js >= 20.19 and npm (found: $(node --version 2>/dev/null || echo none))" >&2
    return 1
  fi
  echo "install-deps: npm ci in web/" >&2
  (cd "$web" && npm ci --no-audit --no-fund --loglevel=error)
}

if [ ${#missing[@]} -eq 0 ]; then
  web_deps
  exit 0
fi

echo "install-deps: installing ${missing[*]}" >&2
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: not root and no sudo; install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends -o DPkg::Lock::Timeout=600 "${missing[@]}"
web_deps
