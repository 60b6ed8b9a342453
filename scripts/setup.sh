#!/usr/bin/env bash
# Set up holodata on a fresh Debian machine: system library for open3d, a virtual environment
# in .venv with holodata and every extra (`all`: ingest, synth, mapping, gt, train with torch==2.13.0's
# CPU wheel, view, export, dask, s3; docs/install.md) and the test tools (`dev`).
# Idempotent: rerunning only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

# Debian packages: libusb for open3d; headless Chromium renders the evaluation report (its test
# and `holodata evaluate --screenshot`)
apt_pkgs=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || apt_pkgs+=(libusb-1.0-0)
command -v chromium-headless-shell >/dev/null 2>&1 || apt_pkgs+=(chromium-headless-shell)
if [ ${#apt_pkgs[@]} -gt 0 ]; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${apt_pkgs[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=.venv/.holodata-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[all,dev]"
    # Ouster's SDK reads Ouster pcap + json; it pins rosbags==0.9.23 (holodata needs >= 0.10 for
    # rosbag2 MCAP), so it goes in without its pins, with the two helpers its readers import. The
    # list lives in holodata.readers.ouster.SDK_REQUIREMENTS (its error message names the same).
    mapfile -t ouster_reqs < <(.venv/bin/python -m holodata.readers.ouster)
    .venv/bin/python -m pip install -q --no-deps "${ouster_reqs[@]}"
    touch "$stamp"
fi
echo "holodata is set up in .venv (activate with: source .venv/bin/activate)" >&2
