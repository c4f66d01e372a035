#!/usr/bin/env bash
# Makes another target ready for tests/other_targets.rs: the Rust standard library for it
# (`rustup target add`), a C compiler and linker for it (ring, SQLite and BLAKE3 compile C),
# and for aarch64 qemu's user-mode emulator, which runs its binaries on this machine.
# Debian's packages, installed with apt when this runs as root on a machine with apt, under
# the lock every helper script takes for apt/dpkg. Exits 0 when the target is ready; exits
# 2 with one line on stderr saying why not (the test then prints SKIPPED with that line).
# Usage: scripts/cross-target.sh aarch64-unknown-linux-gnu | x86_64-unknown-linux-musl
set -euo pipefail
target=${1:?usage: scripts/cross-target.sh TARGET}
case "$target" in
  aarch64-unknown-linux-gnu)
    tools=(aarch64-linux-gnu-gcc qemu-aarch64)
    packages=(gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user)
    ;;
  x86_64-unknown-linux-musl)
    tools=(musl-gcc)
    packages=(musl-tools)
    ;;
  *)
    echo "scripts/cross-target.sh knows no target $target" >&2
    exit 2
    ;;
esac

missing() {
  local t
  for t in "${tools[@]}"; do
    command -v "$t" >/dev/null 2>&1 || return 0
  done
  return 1
}

if missing; then
  # shellcheck source=scripts/apt-install.sh
  . "$(dirname "$0")/apt-install.sh"
  apt_install "no ${tools[*]} for $target" "${packages[@]}"
  if missing; then
    echo "${packages[*]} installed, but ${tools[*]} are not all on PATH" >&2
    exit 2
  fi
fi

# The standard library for the target, in the toolchain that builds the project.
if [ ! -d "$(rustc --print sysroot)/lib/rustlib/$target/lib" ]; then
  if ! command -v rustup >/dev/null 2>&1; then
    echo "the toolchain has no standard library for $target, and there is no rustup to add it" >&2
    exit 2
  fi
  if ! out=$(flock /tmp/tessera-rustup.lock timeout 900 rustup target add "$target" 2>&1); then
    echo "rustup target add $target failed: $(echo "$out" | tail -1)" >&2
    exit 2
  fi
fi

# The tools on PATH are not enough: a C program built for the target must link against
# its C library and run here (under qemu for aarch64, with the loader where the test
# points it: Debian's /usr/aarch64-linux-gnu).
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
printf '#include <stdio.h>\nint main(void) { puts("ok"); return 0; }\n' >"$work/ok.c"
case "$target" in
  aarch64-unknown-linux-gnu)
    built=$(aarch64-linux-gnu-gcc "$work/ok.c" -o "$work/ok" 2>&1) &&
      ran=$(timeout 60 qemu-aarch64 -L /usr/aarch64-linux-gnu "$work/ok" 2>&1) || true
    ;;
  x86_64-unknown-linux-musl)
    built=$(musl-gcc -static "$work/ok.c" -o "$work/ok" 2>&1) && ran=$(timeout 60 "$work/ok" 2>&1) || true
    ;;
esac
if [ "${ran:-}" != ok ]; then
  echo "a C program for $target does not build and run here: $(echo "${built:-}${ran:-}" | head -1)" >&2
  exit 2
fi
