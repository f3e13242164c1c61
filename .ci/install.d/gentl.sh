#!/usr/bin/env bash
# GenTL peers for the handeye-gentl tests, in $REPO/.venv: the EMVA `genicam` package (ships
# viky.cti, the reference GenTL producer of simulated 3D cameras) and harvesters (a GenTL
# consumer that drives viky and our simulated producer). Idempotent.
set -euo pipefail
. "$(dirname "$0")/../apt.sh"
REPO="$(cd "$(dirname "$0")/../.." && pwd)"
if ! command -v python3 >/dev/null 2>&1 || ! python3 -m venv --help >/dev/null 2>&1; then
  apt_install "python3 with venv is missing" python3 python3-venv python3-pip
fi
if [ ! -x "$REPO/.venv/bin/python" ]; then
  python3 -m venv "$REPO/.venv"
fi
if ! "$REPO/.venv/bin/python" -c 'import genicam.genapi, harvesters' >/dev/null 2>&1 \
  || [ "$("$REPO/.venv/bin/python" -c 'import importlib.metadata as m; print(m.version("harvesters"))')" != "1.4.3" ]; then
  "$REPO/.venv/bin/pip" install --quiet genicam harvesters==1.4.3
fi
