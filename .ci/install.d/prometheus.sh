#!/usr/bin/env bash
# promtool for tests/e2e/monitoring.rs (checks monitoring/handeye.rules.yml, its unit tests, the
# Grafana dashboard's queries and a live /metrics). Debian ships promtool only inside the
# `prometheus` package, whose installation also installs (and on a machine with systemd enables
# and starts) the Prometheus server. So the package is downloaded, not installed: promtool is
# taken out of it with `dpkg -x` into /usr/local/bin (a static Go binary: no other files or
# libraries needed). Idempotent; runs as root.
set -euo pipefail

if ! command -v promtool >/dev/null 2>&1; then
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "${0##*/}: promtool is missing and apt-get is unavailable" >&2
    exit 1
  fi
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
  apt-get update
  (cd "$work" && apt-get download prometheus)
  dpkg -x "$work"/prometheus_*.deb "$work/root"
  install -m 0755 "$work/root/usr/bin/promtool" /usr/local/bin/promtool
fi
promtool --version 2>&1 | head -n 1
