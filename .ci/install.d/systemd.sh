#!/usr/bin/env bash
# systemd-analyze for tests/e2e/systemd.rs, which runs `systemd-analyze verify` on
# systemd/handeye.service. Idempotent; runs as root on a fresh Debian machine.
#
# Installing Debian's `systemd` package inside a container starts nothing: its maintainer
# scripts call systemctl only when systemd is the running init (/run/systemd/system exists),
# and `systemd-analyze verify` works offline, without a running manager.
set -euo pipefail
. "$(dirname "$0")/../apt.sh"

if ! command -v systemd-analyze >/dev/null 2>&1; then
  apt_install "systemd-analyze is missing" systemd
fi
systemd-analyze --version | head -n 1
