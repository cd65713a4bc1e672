#!/usr/bin/env bash
# Installs exactly the Debian 12 packages that sonomesh builds, tests and runs with.
# Fast when everything is already there: dpkg is asked first, apt only when something is missing.
set -euo pipefail

packages=(
  # toolchain
  cmake g++ make pkg-config ca-certificates
  # acquire/: USB probes (V4L2 needs only <linux/videodev2.h> from linux-libc-dev)
  libusb-1.0-0-dev linux-libc-dev zlib1g-dev libexpected-dev
  # volume/: smoothing, grids, NRRD, NIfTI-1
  libopencv-core-dev libopencv-imgproc-dev libeigen3-dev libopenvdb-dev libtbb-dev libteem-dev
  libnifti2-dev
  # OpenVDB 10 headers include Boost (numeric/conversion, any, uuid); its -dev package omits them
  libboost-dev
  # segment/ and reconstruct/
  libfftw3-dev
  # sim/: probe-sim serve --igtl (a PlusServer stand-in) packs IMAGE messages with it
  libopenigtlink-dev
  # daemon/
  libcli11-dev libtomlplusplus-dev nlohmann-json3-dev libspdlog-dev libfmt-dev libcpp-httplib-dev
  # daemon/: the OpenIGTLink server uses libopenigtlink-dev (above); the live page (slice
  # PNGs through libpng, three.js served locally), systemd notify
  libpng-dev libjs-three libsystemd-dev
  # tests and benchmarks (HIL tests run the real libusb/V4L2 paths under umockdev; the web
  # tests decode the slice PNGs with imgcodecs)
  libopencv-imgcodecs-dev libgtest-dev libgmock-dev libbenchmark-dev umockdev libumockdev-dev
  # the live page's browser test (headless, WebGL through SwiftShader)
  chromium
  # the sanitizer build and the libFuzzer targets (SONOMESH_SANITIZE / SONOMESH_FUZZ in test.sh)
  clang libclang-rt-14-dev
  # the `format` test (scripts/check_format.sh)
  clang-format-14
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "setup: installing ${missing[*]}" >&2
sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
