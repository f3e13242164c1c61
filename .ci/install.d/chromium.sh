#!/usr/bin/env bash
# Headless Chromium and chromedriver for tests/e2e/web.rs, which drives the daemon's web page
# through chromedriver's WebDriver HTTP protocol. Idempotent; runs as root on a fresh Debian
# machine (Debian's `chromium` and `chromium-driver` packages; nothing is downloaded outside
# the package manager).
set -euo pipefail
. "$(dirname "$0")/../apt.sh"

if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
  apt_install "chromium/chromedriver are missing" chromium chromium-driver fonts-dejavu-core
fi
chromium --version
chromedriver --version
