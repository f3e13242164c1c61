#!/usr/bin/env bash
# mdbook for building the manual (docs/, checked by .ci/run). Debian has no mdbook package and
# nothing but the registries is reachable, so it is built from crates.io: a pinned version,
# --locked, without the `serve`/`watch` features (a web server and a file watcher CI never
# uses; they double the build). Skipped when that version is already installed. Idempotent.
set -euo pipefail
MDBOOK_VERSION=0.5.4
if command -v mdbook >/dev/null 2>&1 && mdbook --version | grep -qx "mdbook v$MDBOOK_VERSION"; then
  mdbook --version
  exit 0
fi
cargo install mdbook --version "$MDBOOK_VERSION" --locked --no-default-features --features search
mdbook --version
