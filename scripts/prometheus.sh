#!/usr/bin/env bash
# Makes Prometheus and promtool available to the metrics tests (coordinator's
# `promtool check metrics`, tests/metrics.rs): Debian's `prometheus` package, downloaded
# with `apt-get download` and unpacked with `dpkg-deb -x` into target/tools/prometheus
# (nothing is installed into the system; `apt_fetch` of scripts/apt-install.sh), under the
# lock every helper script takes for apt/dpkg. Binaries already on PATH are used as they are. Prints the directory holding
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
if ! command -v flock >/dev/null 2>&1; then
  echo "no promtool on PATH and no flock to fetch Debian's prometheus package under the apt lock" >&2
  exit 2
fi
# One lock over the download and the unpacking: apt/dpkg of other helpers wait, and so
# does a second copy of this script (two tests may ask at once), which then finds the
# binaries unpacked.
exec 9>/tmp/tessera-apt.lock
flock 9
if [ -x "$bin/promtool" ] && [ -x "$bin/prometheus" ]; then
  echo "$bin"
  exit 0
fi
# shellcheck source=scripts/apt-install.sh
. scripts/apt-install.sh
apt_fetch "no promtool on PATH" "$dir" prometheus
if [ -x "$bin/promtool" ] && [ -x "$bin/prometheus" ]; then
  echo "$bin"
  exit 0
fi
echo "Debian's prometheus package holds no usr/bin/promtool and usr/bin/prometheus" >&2
exit 2
