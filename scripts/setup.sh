#!/usr/bin/env bash
# Set up holodata on a fresh Debian machine: system library for open3d, a virtual environment
# in .venv with holodata and every extra (`all`: ingest, synth, mapping, gt, train with torch==2.13.0's
# CPU wheel, view, export, dask, s3; docs/install.md) and the test tools (`dev`).
# Idempotent: rerunning only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

# One line per step on stderr (what it did, how long it took); the tools' own output (apt, pip and the
# build backend's warnings) goes to .venv-setup.log, printed only when a step fails.
log="$PWD/.venv-setup.log"
: >"$log"
step() {   # step "what" command...: run it quietly, say how long it took, or show its output and stop
    local what=$1 t0=$SECONDS
    shift
    if "$@" >>"$log" 2>&1; then
        echo "setup: $what ($((SECONDS - t0)) s)" >&2
    else
        echo "setup: $what FAILED; the last lines of $log:" >&2
        tail -n 25 "$log" >&2
        exit 1
    fi
}

# Debian packages: libusb for open3d; headless Chromium renders the evaluation report (its test
# and `holodata evaluate --screenshot`)
apt_pkgs=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || apt_pkgs+=(libusb-1.0-0)
command -v chromium-headless-shell >/dev/null 2>&1 || apt_pkgs+=(chromium-headless-shell)
if [ ${#apt_pkgs[@]} -gt 0 ]; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    step "apt-get update" $SUDO apt-get update -qq
    step "Debian packages: ${apt_pkgs[*]}" env DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq \
        --no-install-recommends "${apt_pkgs[@]}"
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || step "virtual environment .venv ($("$PY" --version 2>&1))" "$PY" -m venv .venv
stamp=.venv/.holodata-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    step "pip upgraded" .venv/bin/python -m pip install -q --upgrade pip
    step "holodata with every extra and the test tools (pip install -e '.[all,dev]')" \
        .venv/bin/python -m pip install -q -e ".[all,dev]"
    # Ouster's SDK reads Ouster pcap + json; it pins rosbags==0.9.23 (holodata needs >= 0.10 for
    # rosbag2 MCAP), so it goes in without its pins, with the two helpers its readers import. The
    # list lives in holodata.readers.ouster.SDK_REQUIREMENTS (its error message names the same).
    mapfile -t ouster_reqs < <(.venv/bin/python -m holodata.readers.ouster)
    step "Ouster SDK (${ouster_reqs[*]}, without its pins)" .venv/bin/python -m pip install -q --no-deps "${ouster_reqs[@]}"
    touch "$stamp"
    echo "setup: .venv holds $(.venv/bin/python -m pip list --format=freeze 2>/dev/null | wc -l) packages," \
         "$(du -sh .venv 2>/dev/null | cut -f1)" >&2
fi
# holodata is installed editable (its modules stay here): byte-compile them once, as pip does for the
# packages it copies, so that a process started with PYTHONDONTWRITEBYTECODE set (this machine kind
# sets it) does not compile every module it imports again (~0.3 s a process: docs/design/performance.md)
step "holodata's modules byte-compiled" .venv/bin/python -m compileall -q holodata
echo "holodata is set up in .venv (activate with: source .venv/bin/activate)" >&2
