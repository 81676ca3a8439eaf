#!/usr/bin/env bash
# One-step, idempotent set-up: Debian runtime library for open3d, a virtual
# environment in .venv, and an editable install of planar-vo with test extras (which pull
# the sim extra: open3d, for the synthetic renderer the demo and the tests use).
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3}

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    echo "setup: installing Debian package libusb-1.0-0 (open3d loads it)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv with $($PY --version)"
    $PY -m venv .venv
fi
stamp=.venv/.planar-vo-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    echo "setup: installing planar-vo (editable) and its dependencies"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e '.[test]'
    touch "$stamp"
fi
.venv/bin/python -c "import planar_vo, open3d, gtsam, cv2, mcap" \
    || { echo "setup: import check failed; remove .venv and run setup.sh again" >&2; exit 1; }
echo "setup: ready (.venv/bin/planar-vo)"
