#!/usr/bin/env bash
# Makes Prometheus and promtool available to the metrics tests (coordinator's
# `promtool check metrics`, tests/metrics.rs): Debian's `prometheus` package, downloaded
# with `apt-get download` and unpacked with `dpkg-deb -x` into target/tools/prometheus
# (nothing is installed into the system), under the lock every helper script takes for
# apt/dpkg. Binaries already on PATH are used as they are. Prints the directory holding
# `prometheus` and `promtool` on stdout and exits 0; exits 2 with one line on stderr
# saying why when they cannot be had (the tests then print SKIPPED with that line).
# Usage: scripts/prometheus.sh
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${CARGO_TARGET_DIR:-$PWD/target}/tools/prometheus
bin=$dir/usr/bin

if command -v promtool >/dev/null 2>&1 && command -v prometheus >/dev/null 2>&1; then
  dirname "$(command -v promtool)"
  exit 0
fi
if [ -x "$bin/promtool" ] && [ -x "$bin/prometheus" ]; then
  echo "$bin"
  exit 0
fi
for tool in apt-get dpkg-deb flock; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "no promtool on PATH and no $tool to unpack Debian's prometheus package" >&2
    exit 2
  fi
done
mkdir -p "$dir"
log=$(mktemp)
work=$(mktemp -d)
trap 'rm -rf "$log" "$work"' EXIT
# One lock over the download and the unpacking: apt/dpkg of other helpers wait, and so
# does a second copy of this script (two tests may ask at once), which then finds the
# binaries unpacked.
exec 9>/tmp/tessera-apt.lock
flock 9
if [ -x "$bin/promtool" ] && [ -x "$bin/prometheus" ]; then
  echo "$bin"
  exit 0
fi
fetch() {
  (cd "$work" && apt-get download prometheus >"$log" 2>&1)
}
# A machine that has never fetched the package lists knows no prometheus yet (updating
# them needs root).
if ! fetch; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update >>"$log" 2>&1 || true
  fi
  if ! fetch; then
    echo "apt-get download prometheus failed: $(grep -E '^E:' "$log" | head -1)" >&2
    exit 2
  fi
fi
deb=$(ls "$work"/prometheus_*.deb | head -1)
if ! dpkg-deb -x "$deb" "$dir" >"$log" 2>&1; then
  echo "dpkg-deb -x $deb failed: $(head -1 "$log")" >&2
  exit 2
fi
if [ -x "$bin/promtool" ] && [ -x "$bin/prometheus" ]; then
  echo "$bin"
  exit 0
fi
echo "Debian's prometheus package holds no usr/bin/promtool and usr/bin/prometheus" >&2
exit 2
