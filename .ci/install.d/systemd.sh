#!/usr/bin/env bash
# systemd-analyze for tests/e2e/systemd.rs, which runs `systemd-analyze verify` on
# systemd/handeye.service. Idempotent; runs as root on a fresh Debian machine.
#
# Installing Debian's `systemd` package inside a container starts nothing: its maintainer
# scripts call systemctl only when systemd is the running init (/run/systemd/system exists),
# and `systemd-analyze verify` works offline, without a running manager.
set -euo pipefail

if ! command -v systemd-analyze >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends systemd
  else
    echo "systemd.sh: systemd-analyze is missing and apt-get is unavailable" >&2
    exit 1
  fi
fi
systemd-analyze --version | head -n 1
