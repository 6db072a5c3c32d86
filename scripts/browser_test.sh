#!/usr/bin/env bash
# The viewer in a real browser: headless Chromium (Debian's `chromium`, or $CHROMIUM) loads
# `nerf view --config lego`, drags, zooms, records a camera path and renders it. A thin wrapper
# over the Rust integration test apps/nerf/tests/browser.rs (which `cargo test --release` also runs).
#   scripts/browser_test.sh [SCREENSHOT.png]
# Chromium missing: `.ci/install` installs it (the test prints SKIPPED without it).
set -euo pipefail
if [ -n "${1:-}" ]; then
  # Resolved before the cd below, so a relative path means one relative to the caller.
  NERF_BROWSER_SCREENSHOT=$(realpath -m "$1")
  export NERF_BROWSER_SCREENSHOT
fi
cd "$(dirname "$0")/.."
exec cargo test --release --test browser -- --nocapture
