#!/usr/bin/env bash
# Unpacks Debian's `assimp-testmodels` package (the Khronos glTF 2.0 sample models and
# invalid files among Assimp's test models) into target/assimp-testmodels, for
# tests/gltf_models.rs. Nothing is installed into the system: `apt-get download` fetches
# the .deb (under the lock every helper script takes for apt/dpkg, after `apt-get update`
# if the package lists do not know it yet) and `dpkg-deb -x` unpacks it. Prints the
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
for tool in apt-get dpkg-deb flock; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "no $tool here to fetch Debian's assimp-testmodels package" >&2
    exit 2
  fi
done
mkdir -p "$dest/deb"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
download() {
  (cd "$dest/deb" && flock /tmp/tessera-apt.lock apt-get download assimp-testmodels >"$log" 2>&1)
}
if ! download; then
  # A machine that has never fetched the package lists knows no such package yet.
  if [ "$(id -u)" = 0 ]; then
    flock /tmp/tessera-apt.lock apt-get update >>"$log" 2>&1 || true
  fi
  if ! download; then
    echo "apt-get download assimp-testmodels failed: $(grep -E '^E:' "$log" | head -1)" >&2
    exit 2
  fi
fi
deb=$(ls "$dest"/deb/assimp-testmodels_*.deb 2>/dev/null | head -1)
if [ -z "$deb" ]; then
  echo "apt-get download assimp-testmodels left no .deb in $dest/deb" >&2
  exit 2
fi
dpkg-deb -x "$deb" "$dest/root"
touch "$dest/.unpacked"
if find_gltf2; then
  exit 0
fi
echo "the assimp-testmodels package holds no glTF2 folder" >&2
exit 2
