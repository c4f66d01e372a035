#!/usr/bin/env bash
# Unpacks Debian's `assimp-testmodels` package (the Khronos glTF 2.0 sample models and
# invalid files among Assimp's test models) into target/assimp-testmodels, for
# tests/gltf_models.rs. Nothing is installed into the system: `apt_fetch` of
# scripts/apt-install.sh downloads the .deb with `apt-get download` (under the lock every
# helper script takes for apt/dpkg, after `apt-get update` if the package lists do not
# know it yet) and unpacks it with `dpkg-deb -x`. Prints the
# unpacked tree's glTF 2.0 folder on stdout and exits 0; exits 2 with one line on stderr
# saying why when it cannot be had (the test then prints SKIPPED with that line).
# Usage: scripts/assimp-testmodels.sh [target-dir]
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
target=${1:-${CARGO_TARGET_DIR:-$here/target}}
dest=$target/assimp-testmodels

find_gltf2() {
  local d
  d=$(find "$dest" -type d -name glTF2 2>/dev/null | head -1)
  [ -n "$d" ] && echo "$d"
}

if [ -f "$dest/.unpacked" ] && find_gltf2; then
  exit 0
fi
if ! command -v flock >/dev/null 2>&1; then
  echo "no flock here to fetch Debian's assimp-testmodels package under the apt lock" >&2
  exit 2
fi
# One lock over the download and the unpacking: apt/dpkg of other helpers wait, and so
# does a second copy of this script, which then finds the models unpacked.
exec 9>/tmp/tessera-apt.lock
flock 9
if [ -f "$dest/.unpacked" ] && find_gltf2; then
  exit 0
fi
# shellcheck source=scripts/apt-install.sh
. "$here/scripts/apt-install.sh"
apt_fetch "no glTF sample models in $dest" "$dest/root" assimp-testmodels
touch "$dest/.unpacked"
if find_gltf2; then
  exit 0
fi
echo "the assimp-testmodels package holds no glTF2 folder" >&2
exit 2
