#!/usr/bin/env bash
# Headless Chromium and chromedriver for tests/e2e/web.rs, which drives the daemon's web page
# through chromedriver's WebDriver HTTP protocol. Idempotent; runs as root on a fresh Debian
# machine (Debian's `chromium` and `chromium-driver` packages; nothing is downloaded outside
# the package manager).
set -euo pipefail

if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends chromium chromium-driver fonts-dejavu-core
  else
    echo "chromium.sh: chromium/chromedriver are missing and apt-get is unavailable" >&2
    exit 1
  fi
fi
chromium --version
chromedriver --version
