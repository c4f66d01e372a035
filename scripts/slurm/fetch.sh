#!/usr/bin/env bash
# Unpacks Debian's Slurm (22.05 on bookworm) and MUNGE into a cache directory, without a
# system install, for tests/slurm.rs and for trying deploy/slurm/ on one machine.
#
#   scripts/slurm/fetch.sh [DIR]      (default: target/tools/slurm under the repository)
#
# `apt-get download` + `dpkg-deb -x` into DIR/root; then every unpacked binary and plugin
# is checked with ldd, and each shared library this machine lacks is fetched the same way
# (Debian names a library's package after its soname: libhwloc.so.15 -> libhwloc15,
# liblua5.1.so.0 -> liblua5.1-0), until nothing is missing. The second run finds
# DIR/.complete and does nothing. Every apt-get call holds /tmp/tessera-apt.lock, so that
# helpers installing packages at the same time do not collide.
#
# What the cache holds besides DIR/root:
#   DIR/sbin/slurmstepd  a link to the unpacked slurmstepd. slurmd runs the stepd from a
#                        path compiled in (/usr/sbin/slurmstepd); the test overlays this
#                        directory on /usr/sbin in slurmd's private mount namespace.
#   DIR/env.sh           PATH and LD_LIBRARY_PATH for the unpacked binaries.
# Prints DIR on success.
set -euo pipefail
repo=$(cd "$(dirname "$0")/../.." && pwd)
dest=${1:-$repo/target/tools/slurm}
mkdir -p "$(dirname "$dest")"
dest=$(cd "$(dirname "$dest")" && pwd)/$(basename "$dest")
# Bump when the package list or the layout changes: an older cache is then rebuilt.
stamp="slurm-wlm 22.05 + munge, layout 1"
if [ -f "$dest/.complete" ] && [ "$(cat "$dest/.complete")" = "$stamp" ]; then
  echo "$dest"
  exit 0
fi
# One fetch at a time per cache (a second waits, then finds the cache made).
exec 9>"$dest.lock"
flock 9
if [ -f "$dest/.complete" ] && [ "$(cat "$dest/.complete")" = "$stamp" ]; then
  echo "$dest"
  exit 0
fi
for tool in apt-get apt-cache dpkg-deb ldd flock; do
  command -v "$tool" >/dev/null || { echo "fetch.sh: $tool not found (needs a Debian system)" >&2; exit 2; }
done
apt_locked() { flock /tmp/tessera-apt.lock "$@"; }

# The daemons, the commands, their plugins and libraries, and MUNGE.
packages=(slurmctld slurmd slurm-client slurm-wlm-basic-plugins libslurm38 munge libmunge2)
if ! apt-cache show "${packages[@]}" >/dev/null 2>&1; then
  # No package lists yet (a fresh machine): fetch them once.
  apt_locked apt-get update -qq || { echo "fetch.sh: apt-get update failed" >&2; exit 2; }
  apt-cache show "${packages[@]}" >/dev/null 2>&1 ||
    { echo "fetch.sh: the apt sources have no ${packages[*]}" >&2; exit 2; }
fi

work="$dest.partial.$$"
rm -rf "$work"
mkdir -p "$work/debs" "$work/root"
trap 'rm -rf "$work"' EXIT
fetch() { # apt-get download PACKAGES into $work/debs and unpack them into $work/root
  # apt's sandbox user cannot write into a root-owned directory: let it.
  chmod 0777 "$work/debs"
  (cd "$work/debs" && apt_locked apt-get download -qq "$@") ||
    { echo "fetch.sh: apt-get download $* failed" >&2; exit 2; }
  for p in "$@"; do
    for deb in "$work/debs/${p}"_*.deb; do dpkg-deb -x "$deb" "$work/root"; done
  done
}
fetch "${packages[@]}"

lib="$work/root/usr/lib/x86_64-linux-gnu"
missing() { # sonames that an unpacked binary or plugin needs and neither it nor the system has
  local f
  for f in "$work"/root/usr/sbin/* "$work"/root/usr/bin/* "$lib"/*.so* "$lib"/slurm-wlm/*.so; do
    [ -f "$f" ] && [ ! -L "$f" ] || continue
    LD_LIBRARY_PATH="$lib:$lib/slurm-wlm" ldd "$f" 2>/dev/null | awk '/not found/ { print $1 }'
  done | sort -u
}
package_of() { # Debian's package name for a soname: libNAME.so.V -> libNAMEV, or libNAME-V
  local base=${1%%.so.*} version=${1#*.so.}
  case $base in *[0-9]) echo "$base-$version" ;; *) echo "$base$version" ;; esac
}
declare -A tried=()
for _ in 1 2 3 4 5 6; do
  need=$(missing)
  [ -n "$need" ] || break
  extra=()
  for soname in $need; do
    p=$(package_of "$soname")
    if [ -n "${tried[$p]:-}" ] || ! apt-cache show "$p" >/dev/null 2>&1; then
      echo "fetch.sh: $soname is needed and no package $p provides it" >&2
      exit 2
    fi
    tried[$p]=1
    extra+=("$p")
  done
  echo "fetch.sh: also fetching ${extra[*]} (linked by the unpacked binaries)" >&2
  fetch "${extra[@]}"
done
if [ -n "$(missing)" ]; then
  echo "fetch.sh: still missing after fetching dependencies: $(missing | tr '\n' ' ')" >&2
  exit 2
fi

# The daemons under their plain names (Debian installs these links with update-alternatives).
ln -sf slurmctld-wlm "$work/root/usr/sbin/slurmctld"
ln -sf slurmd-wlm "$work/root/usr/sbin/slurmd"
ln -sf slurmstepd-wlm "$work/root/usr/sbin/slurmstepd"
rm -rf "$work/debs"
rm -rf "$dest"
mv "$work" "$dest"
trap - EXIT
mkdir -p "$dest/sbin"
ln -sf "$dest/root/usr/sbin/slurmstepd-wlm" "$dest/sbin/slurmstepd"
cat >"$dest/env.sh" <<EOF
# Source this to run the unpacked Slurm and MUNGE.
export PATH="$dest/root/usr/bin:$dest/root/usr/sbin:\$PATH"
export LD_LIBRARY_PATH="$dest/root/usr/lib/x86_64-linux-gnu:$dest/root/usr/lib/x86_64-linux-gnu/slurm-wlm\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
EOF
echo "$stamp" >"$dest/.complete"
echo "$dest"
