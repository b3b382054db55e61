#!/usr/bin/env bash
# Installs the Debian packages Concord needs to build and test, and only those missing.
# Idempotent: a second run installs nothing. Used by both README commands and by .ci/run.
set -euo pipefail

packages=(
  build-essential cmake ninja-build ccache pkg-config
  libeigen3-dev            # estimator (the only dependency of estimator/)
  libyaml-cpp-dev          # configuration files
  libcli11-dev             # command-line parsing
  nlohmann-json3-dev       # metrics.json, dataset.json, HTTP bodies
  libopencv-core-dev libopencv-imgproc-dev libopencv-imgcodecs-dev  # trajectory plots (PNG), images
  libopencv-features2d-dev libopencv-video-dev libopencv-calib3d-dev  # stereo front-end (frontend/)
  libboost-dev             # Asio (peer-to-peer network) and Beast (HTTP endpoint), header-only
  libprotobuf-dev protobuf-compiler  # wire schema (proto/)
  libspdlog-dev            # daemon logging, one event per line
  libsodium-dev            # team key and the authenticated peer channel (crypto_kx, secretstream)
  libsystemd-dev           # sd_notify: readiness and the watchdog under systemd (Type=notify)
  libgtest-dev libgmock-dev  # tests
  iproute2                 # ip, tc: the network-namespace team tests (skipped without root)
  clang libclang-rt-14-dev   # sanitizer builds and the libFuzzer targets (scripts/test.sh)
  chromium                 # headless: the live map page's screenshot test
)

missing=()
for package in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q 'install ok installed'; then
    missing+=("$package")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages already installed" >&2
  exit 0
fi

echo "install-deps: installing ${missing[*]}" >&2
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
