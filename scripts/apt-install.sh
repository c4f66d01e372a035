# Sourced by the helper scripts that get Debian packages. `apt_install WHAT PACKAGE...`
# (chromium.sh, cross-target.sh) installs the packages with apt-get,
# under the lock every helper script takes for apt/dpkg, fetching the package lists
# once if the first try fails (a fresh machine knows no packages yet). WHAT says what is
# missing; where the packages cannot be installed (no apt-get, not root, apt failed) it
# prints one line on stderr beginning with it and exits 2, which the tests turn into
# SKIPPED with that line. Every wait is bounded: apt's and dpkg's locks (a fresh machine
# may be running unattended upgrades) and the commands themselves.
apt_install() {
  local what=$1
  shift
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "$what, and no apt-get to install $*" >&2
    exit 2
  fi
  if [ "$(id -u)" != 0 ]; then
    echo "$what, and installing $* needs root" >&2
    exit 2
  fi
  local log
  log=$(mktemp)
  if ! apt_install_once "$log" "$@"; then
    flock /tmp/tessera-apt.lock timeout 600 apt-get update >>"$log" 2>&1 || true
    if ! apt_install_once "$log" "$@"; then
      echo "$what, and apt-get install $* failed: $(grep -E '^E:' "$log" | head -1)" >&2
      rm -f "$log"
      exit 2
    fi
  fi
  rm -f "$log"
}

apt_install_once() {
  local log=$1
  shift
  DEBIAN_FRONTEND=noninteractive flock /tmp/tessera-apt.lock timeout 900 \
    apt-get install -y --no-install-recommends -o DPkg::Lock::Timeout=300 "$@" >>"$log" 2>&1
}

# `apt_fetch WHAT DIR PACKAGE...` (prometheus.sh, openexr-tools.sh,
# assimp-testmodels.sh) downloads the packages with `apt-get download` and unpacks them
# with `dpkg-deb -x` into DIR: nothing is installed into the system, and no root is
# needed unless the package lists must be fetched first (once, after a failed download).
# The caller holds /tmp/tessera-apt.lock (a second flock on it from here would wait for
# the caller). Failures as apt_install's: one line beginning with WHAT, exit 2.
apt_fetch() {
  local what=$1 dir=$2
  shift 2
  local tool
  for tool in apt-get dpkg-deb; do
    if ! command -v "$tool" >/dev/null 2>&1; then
      echo "$what, and no $tool to fetch Debian's $*" >&2
      exit 2
    fi
  done
  local log work deb
  log=$(mktemp)
  work=$(mktemp -d)
  if ! apt_download_once "$work" "$log" "$@"; then
    if [ "$(id -u)" = 0 ]; then
      timeout 600 apt-get update >>"$log" 2>&1 || true
    fi
    if ! apt_download_once "$work" "$log" "$@"; then
      echo "$what, and apt-get download $* failed: $(grep -E '^E:' "$log" | head -1)" >&2
      rm -rf "$log" "$work"
      exit 2
    fi
  fi
  mkdir -p "$dir"
  for deb in "$work"/*.deb; do
    if [ ! -e "$deb" ] || ! dpkg-deb -x "$deb" "$dir" >"$log" 2>&1; then
      echo "$what, and unpacking $(basename "$deb") failed: $(head -1 "$log")" >&2
      rm -rf "$log" "$work"
      exit 2
    fi
  done
  rm -rf "$log" "$work"
}

apt_download_once() {
  local work=$1 log=$2
  shift 2
  (cd "$work" && timeout 600 apt-get download "$@" >>"$log" 2>&1)
}
