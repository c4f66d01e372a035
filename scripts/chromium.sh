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
if ! command -v apt-get >/dev/null 2>&1; then
  echo "no chromium on PATH and no apt-get to install Debian's chromium package" >&2
  exit 2
fi
if [ "$(id -u)" != 0 ]; then
  echo "no chromium on PATH, and installing Debian's chromium package needs root" >&2
  exit 2
fi
log=$(mktemp)
trap 'rm -f "$log"' EXIT
install() {
  DEBIAN_FRONTEND=noninteractive flock /tmp/tessera-apt.lock \
    apt-get install -y --no-install-recommends chromium fonts-dejavu-core >"$log" 2>&1
}
# A machine that has never fetched the package lists knows no chromium yet.
if ! install; then
  flock /tmp/tessera-apt.lock apt-get update >>"$log" 2>&1 || true
  if ! install; then
    echo "apt-get install chromium failed: $(grep -E '^E:' "$log" | head -1)" >&2
    exit 2
  fi
fi
if find_browser; then
  exit 0
fi
echo "chromium was installed but is not on PATH" >&2
exit 2
