#!/usr/bin/env bash
# Makes OpenEXR's own command-line tools available to the AOV test (tests/aov.rs reads
# Tessera's multi-layer EXR back with `exrheader`, a reader nobody here wrote): Debian's
# `openexr` package and the two libraries it links (`libopenexr-3-1-30`, `libimath-3-1-29`;
# other releases' names are looked up with apt-cache), downloaded with `apt-get download`
# and unpacked with `dpkg-deb -x` into target/tools/openexr (nothing is installed into the
# system; `apt_fetch` of scripts/apt-install.sh), under the lock every helper script takes for apt/dpkg. An `exrheader` already
# on PATH is used as it is.
# Prints two lines on stdout and exits 0: the directory holding `exrheader`, then the
# directory to put on LD_LIBRARY_PATH (empty for a system install). Exits 2 with one line
# on stderr saying why when the tools cannot be had (the test then prints SKIPPED).
# Usage: scripts/openexr-tools.sh
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${CARGO_TARGET_DIR:-$PWD/target}/tools/openexr
bin=$dir/usr/bin
lib=

if command -v exrheader >/dev/null 2>&1; then
  dirname "$(command -v exrheader)"
  echo
  exit 0
fi
# Unpacked, and every library it links found beside it or in the system.
found() {
  lib=$(printf '%s:' "$dir"/usr/lib/*-linux-gnu)
  lib=${lib%:}
  [ -x "$bin/exrheader" ] && ! LD_LIBRARY_PATH=$lib ldd "$bin/exrheader" 2>/dev/null | grep -q "not found"
}
if found; then
  echo "$bin"
  echo "$lib"
  exit 0
fi
for tool in apt-cache flock; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "no exrheader on PATH and no $tool to unpack Debian's openexr package" >&2
    exit 2
  fi
done
mkdir -p "$dir"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
# One lock over the look-ups, the download and the unpacking: apt/dpkg of other helpers
# wait, and so does a second copy of this script, which then finds the tools unpacked.
exec 9>/tmp/tessera-apt.lock
flock 9
if found; then
  echo "$bin"
  echo "$lib"
  exit 0
fi
# The package and the libraries it depends on by name (libopenexr-*, libimath-*), so
# that another Debian release's sonames work too.
packages() {
  echo openexr
  apt-cache depends openexr 2>/dev/null | awk '/Depends: lib(openexr|imath)/ {print $2}'
}
if [ -z "$(packages | sed 1d)" ] && [ "$(id -u)" = 0 ]; then
  # A machine that has never fetched the package lists knows no openexr yet.
  timeout 600 apt-get update >"$log" 2>&1 || true
fi
want=$(packages)
if [ -z "$(echo "$want" | sed 1d)" ]; then
  echo "apt-cache knows no openexr package with its libraries (no package lists?)" >&2
  exit 2
fi
# shellcheck source=scripts/apt-install.sh
. scripts/apt-install.sh
# shellcheck disable=SC2086
apt_fetch "no exrheader on PATH" "$dir" $want
if found; then
  echo "$bin"
  echo "$lib"
  exit 0
fi
echo "Debian's openexr package unpacked, but $bin/exrheader does not run with its libraries" >&2
exit 2
