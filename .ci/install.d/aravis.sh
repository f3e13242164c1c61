#!/usr/bin/env bash
# Real GigE Vision peers for the handeye-gige tests: aravis (fake camera, arv-tool,
# arv-camera-test), iproute2 for network namespaces, and the EMVA `genicam` Python package
# (reference GenApi) in $REPO/.venv to validate the simulated camera's XML. Idempotent.
set -euo pipefail
. "$(dirname "$0")/../apt.sh"
REPO="$(cd "$(dirname "$0")/../.." && pwd)"
need=()
for bin in arv-fake-gv-camera-0.8 arv-tool-0.8 arv-camera-test-0.8 ip python3; do
  command -v "$bin" >/dev/null 2>&1 || need+=("$bin")
done
if [ "${#need[@]}" -gt 0 ] || ! python3 -m venv --help >/dev/null 2>&1; then
  apt_install "aravis, iproute2 or python3 with venv are missing" aravis-tools aravis-tools-cli \
    iproute2 python3 python3-venv python3-pip
fi
if [ ! -x "$REPO/.venv/bin/python" ]; then
  python3 -m venv "$REPO/.venv"
fi
if ! "$REPO/.venv/bin/python" -c 'import genicam.genapi' >/dev/null 2>&1; then
  "$REPO/.venv/bin/pip" install --quiet genicam
fi
