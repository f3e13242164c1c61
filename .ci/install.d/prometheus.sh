#!/usr/bin/env bash
# promtool for tests/e2e/monitoring.rs (checks monitoring/handeye.rules.yml, its unit tests, the
# Grafana dashboard's queries and a live /metrics). Debian's `prometheus` package ships it;
# installing it in a container starts no server (no systemd as init). Idempotent; runs as root.
set -euo pipefail

if ! command -v promtool >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends prometheus
  else
    echo "prometheus.sh: promtool is missing and apt-get is unavailable" >&2
    exit 1
  fi
fi
promtool --version 2>&1 | head -n 1
