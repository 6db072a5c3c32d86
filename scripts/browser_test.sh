#!/usr/bin/env bash
# The viewer in a real browser: headless Chromium (Debian's `chromium`, or $CHROMIUM) loads
# `nerf view --config lego`, drags, zooms, records a camera path and renders it.
#   scripts/browser_test.sh [SCREENSHOT.png]
# Needs node and npm; installs playwright-core (tests/browser/package-lock.json) on first use.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
if [ ! -d tests/browser/node_modules/playwright-core ]; then
  (cd tests/browser && npm ci --no-audit --no-fund --silent)
fi
node tests/browser/viewer.mjs target/release/nerf "${1:-}" lego
