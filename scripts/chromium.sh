#!/usr/bin/env bash
# Makes headless Chromium available for the dashboard's browser test (tests/dashboard.rs):
# Debian's `chromium` package, installed with apt when this runs as root on a machine
# with apt, under the lock every helper script takes for apt/dpkg. Prints the path of
# the browser on stdout and exits 0; exits 2 with one line on stderr saying why when it
# cannot be had (the test then prints SKIPPED with that line).
# Usage: scripts/chromium.sh
set -euo pipefail

find_browser() {
  local b
  for b in "${TESSERA_CHROMIUM:-}" chromium chromium-browser google-chrome; do
    [ -n "$b" ] || continue
    if command -v "$b" >/dev/null 2>&1; then
      command -v "$b"
      return 0
    fi
  done
  return 1
}

if find_browser; then
  exit 0
fi
# shellcheck source=scripts/apt-install.sh
. "$(dirname "$0")/apt-install.sh"
apt_install "no chromium on PATH" chromium fonts-dejavu-core
if find_browser; then
  exit 0
fi
echo "chromium was installed but is not on PATH" >&2
exit 2
