#!/usr/bin/env bash
# Installs the real UR clients `ur-rtde` (SDU, PyPI) and `urx` (python-urx, PyPI, with its
# dependency math3d) into $REPO/.venv for the peer tests in drivers/ur/tests and tests/e2e.
# Idempotent; runs as root on a fresh Debian machine.
set -euo pipefail
. "$(dirname "$0")/../apt.sh"
REPO="$(cd "$(dirname "$0")/../.." && pwd)"
UR_RTDE_VERSION="1.6.5"
URX_VERSION="0.11.0"
MATH3D_VERSION="4.0.0"

if ! command -v python3 >/dev/null 2>&1 || ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then
  apt_install "python3 with venv is missing" python3 python3-venv python3-pip
fi

# ur-rtde 1.6.5 ships wheels for CPython 3.7–3.12 only. On a newer Python (Debian 13) pip builds
# it from source, which needs a compiler, CMake and Boost (untested here: Debian 12 has 3.11).
if ! python3 -c 'import sys; sys.exit(sys.version_info >= (3, 13))' && command -v apt-get >/dev/null 2>&1; then
  apt_install "a compiler for ur-rtde is missing" build-essential cmake python3-dev \
    libboost-system-dev libboost-thread-dev libboost-program-options-dev
fi

if [ ! -x "$REPO/.venv/bin/python" ]; then
  python3 -m venv "$REPO/.venv"
fi
if ! "$REPO/.venv/bin/python" -c "import rtde_receive, rtde_io, dashboard_client, sys; \
import importlib.metadata as m; sys.exit(m.version('ur_rtde') != '$UR_RTDE_VERSION')" >/dev/null 2>&1; then
  "$REPO/.venv/bin/python" -m pip install --quiet --upgrade pip
  "$REPO/.venv/bin/python" -m pip install --quiet "ur-rtde==$UR_RTDE_VERSION"
fi
if ! "$REPO/.venv/bin/python" -c "import urx, sys; \
import importlib.metadata as m; sys.exit(m.version('urx') != '$URX_VERSION')" >/dev/null 2>&1; then
  "$REPO/.venv/bin/python" -m pip install --quiet "urx==$URX_VERSION" "math3d==$MATH3D_VERSION"
fi
"$REPO/.venv/bin/python" -c "import rtde_receive, rtde_control, rtde_io, dashboard_client; print('ur-rtde ready')"
"$REPO/.venv/bin/python" -c "import urx; print('urx ready')"
