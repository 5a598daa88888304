#!/usr/bin/env bash
# Installs what eprop needs on a fresh Debian 12 machine (only what is missing) and builds it.
# Used by demo.sh and test.sh; safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

pkgs=(libopenmpi-dev openmpi-bin libclang-dev libmetis-dev libhdf5-openmpi-dev hdf5-tools pkg-config libhypre-dev libptscotch-dev libsuitesparse-dev
      python3-h5py python3-numpy python3-matplotlib python3-venv tetgen gmsh
      libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
if ! command -v cargo >/dev/null; then
  echo "setup: cargo not found; install Rust (https://rustup.rs) first" >&2
  exit 1
fi
cargo build --release --quiet
# post-processing environment (scripts/requirements.txt) in .venv, refreshed when it changes
py=$(command -v python3)
if [ ! -x .venv/bin/python ] || [ scripts/requirements.txt -nt .venv/.stamp ]; then
  echo "setup: python environment .venv (scripts/requirements.txt)"
  "$py" -m venv .venv
  .venv/bin/pip install -q --disable-pip-version-check -r scripts/requirements.txt
  touch .venv/.stamp
fi
