#!/usr/bin/env bash
# Installs every Debian 12 package octoray builds, tests and benchmarks with (by name; see
# docs/dependencies.md for why each is here). Does nothing when all are already installed.
set -euo pipefail

packages=(
  # toolchain
  build-essential cmake ninja-build pkg-config
  # fuzzing (scripts/test.sh): clang with libFuzzer and its sanitizer runtimes
  clang libclang-rt-14-dev
  # libraries
  libgdcm-dev libvtk9-dev libopencv-dev libtiff-dev libpng-dev libopenexr-dev zlib1g-dev libtbb-dev libzstd-dev liblz4-dev libxxhash-dev
  nlohmann-json3-dev libcli11-dev libfmt-dev libexpat1-dev
  # PACS: DICOMweb over libcurl, DIMSE through DCMTK's network library; OpenVDB in and out
  libcurl4-openssl-dev libdcmtk-dev libopenvdb-dev libboost-iostreams-dev liblog4cplus-dev
  # batch: HMAC-SHA256 of patient IDs in output paths
  libssl-dev
  # rendering: GL loader, headless EGL on Mesa (llvmpipe without a GPU), GLFW windows, Xvfb for window tests
  libepoxy-dev libegl-dev libegl-mesa0 libgl1-mesa-dri libglfw3-dev libgl-dev libimgui-dev libstb-dev fonts-dejavu-core xvfb xauth
  # tests: GoogleTest, and independent references for DICOM decoding and conversion
  libgtest-dev libgmock-dev libgdcm-tools dcm2niix python3 python3-pydicom python3-numpy python3-pil
  # PACS tests: a real Orthanc with its DICOMweb plugin, started by the tests on the loopback
  # interface; openssl makes their self-signed certificate
  orthanc orthanc-dicomweb openssl
  # batch tests: a one-node Slurm cluster (slurmctld, slurmd, munged) started by the tests on
  # this machine with their own config and state (tests/batch/slurm_cluster.sh)
  slurm-wlm munge
  # benchmarks: plots of bench/plot_accuracy.py
  python3-matplotlib
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]} == 0)); then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo=()
if ((EUID != 0)); then
  command -v sudo >/dev/null || { echo "install-deps: run as root (missing: ${missing[*]})" >&2; exit 1; }
  sudo=(sudo)
fi
echo "install-deps: installing ${missing[*]}"
"${sudo[@]}" apt-get update
DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y --no-install-recommends "${missing[@]}"
