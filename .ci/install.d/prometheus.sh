#!/usr/bin/env bash
# promtool for tests/e2e/monitoring.rs (checks monitoring/handeye.rules.yml, its unit tests, the
# Grafana dashboard's queries and a live /metrics). Debian's `prometheus` package ships it;
# installing it in a container starts no server (no systemd as init). Idempotent; runs as root.
set -euo pipefail
. "$(dirname "$0")/../apt.sh"

if ! command -v promtool >/dev/null 2>&1; then
  apt_install "promtool is missing" prometheus
fi
promtool --version 2>&1 | head -n 1
