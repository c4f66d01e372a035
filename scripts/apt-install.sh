# Sourced by the helper scripts that install Debian packages (chromium.sh,
# cross-target.sh): `apt_install WHAT PACKAGE...` installs the packages with apt-get,
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
