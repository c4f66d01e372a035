#!/usr/bin/env bash
# Builds `tessera` with profile-guided optimisation: an instrumented release build renders
# every scene in scenes/ (the tracer alone through `bench samples`, and one small farm
# render for the coordinator, the gRPC path and the image writers), LLVM merges the counts,
# and a second release build lays out and inlines the code by them. The image does not
# change (PGO moves code, not arithmetic): every scene's checksum from the optimised binary
# is compared with the instrumented one's before the script says it is done.
#
# Usage: scripts/pgo-build.sh [TARGET_DIR]   (default target/pgo)
# Prints the optimised binary's path on the last line of stdout. Exits 0 when it is built
# and checked; 1 when a build, a training run or a checksum fails; 2 with one line on
# stderr when this toolchain cannot do PGO (no llvm-profdata and no rustup to add it).
# Takes two full release builds (about 9 minutes on 2 cores) and a minute of training.
# The caller's flags (RUSTFLAGS, or CARGO_ENCODED_RUSTFLAGS, e.g. -C target-cpu=native)
# are kept for both builds; a `build.rustflags` in a cargo config file is not (cargo lets
# the environment replace it), so put such flags in RUSTFLAGS.
set -euo pipefail
# The target directory as the caller named it, from where the caller stands.
dir=${1:-}
here=$(pwd)
cd "$(dirname "$0")/.."
case "$dir" in
  "") dir=target/pgo ;;
  /*) ;;
  *) dir="$here/$dir" ;;
esac
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
rustc=${RUSTC:-rustc}

# llvm-profdata must match the LLVM inside rustc (its profile format changes between LLVM
# versions), so it is the one rustup ships as the llvm-tools component, not the distro's.
host=$("$rustc" -vV | sed -n 's/^host: //p')
profdata="$("$rustc" --print sysroot)/lib/rustlib/$host/bin/llvm-profdata"
if [ ! -x "$profdata" ]; then
  if ! command -v rustup >/dev/null 2>&1; then
    echo "this toolchain has no llvm-profdata (rustup's llvm-tools) and there is no rustup to add it" >&2
    exit 2
  fi
  if ! out=$(flock /tmp/tessera-rustup.lock timeout 900 rustup component add llvm-tools 2>&1); then
    echo "rustup component add llvm-tools failed: $(echo "$out" | tail -1)" >&2
    exit 2
  fi
  if [ ! -x "$profdata" ]; then
    echo "rustup added llvm-tools, but $profdata is not there" >&2
    exit 2
  fi
fi

# Flags go to cargo as CARGO_ENCODED_RUSTFLAGS (separated by 0x1f), which cargo prefers to
# RUSTFLAGS and does not split on spaces, so a path with a space survives.
sep=$'\x1f'
if [ -n "${CARGO_ENCODED_RUSTFLAGS:-}" ]; then
  base="$CARGO_ENCODED_RUSTFLAGS$sep"
else
  base=""
  read -r -a split <<<"${RUSTFLAGS:-}"
  for f in "${split[@]}"; do base+="$f$sep"; done
fi
unset RUSTFLAGS CARGO_ENCODED_RUSTFLAGS
profiles="$dir/profiles"
rm -rf "$profiles"
mkdir -p "$profiles"

echo "== instrumented build (target dir $dir/gen)" >&2
CARGO_ENCODED_RUSTFLAGS="$base-Cprofile-generate=$profiles" \
  "${CARGO:-cargo}" build --release --locked --bin tessera --target-dir "$dir/gen" >&2
gen="$dir/gen/release/tessera"

# The training set: every scene whose assets are here (the terrain's mesh is generated, not
# kept in git: it is trained on when it has been generated). The sizes keep the whole set
# near a minute under instrumentation while every material, light, shape and sampler path
# runs many times; the counts only need the branches' proportions, not precision.
scenes=()
while IFS= read -r s; do
  case "$s" in
    scenes/terrain/terrain.toml) [ -f scenes/terrain/terrain.obj ] || continue ;;
  esac
  scenes+=("$s")
done < <(find scenes -name '*.toml' ! -name '.*' | sort)
[ "${#scenes[@]}" -gt 0 ] || { echo "no scenes under scenes/" >&2; exit 1; }

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# %4m: the processes merge their counts into four files as they exit, instead of leaving
# one 11 MB file each (a farm render starts several).
export LLVM_PROFILE_FILE="$profiles/tessera-%4m.profraw"
echo "== training on ${#scenes[@]} scenes" >&2
for s in "${scenes[@]}"; do
  name=$(echo "$s" | tr / _)
  "$gen" bench samples "$s" --size 128x96 --spp 16 --threads 1 --runs 1 >"$work/$name.gen" ||
    { echo "training on $s failed" >&2; exit 1; }
done
# The farm: coordinator, worker processes, leases and merges, the PNG.
if ! "$gen" render scenes/cornell.toml --size 96x72 --spp 8 --workers 2 --data "$work/data" -o "$work/farm.png" \
  >"$work/farm.log" 2>&1; then
  echo "the training render of scenes/cornell.toml failed: $(tail -1 "$work/farm.log")" >&2
  exit 1
fi
unset LLVM_PROFILE_FILE

# Named by its content: cargo rebuilds a crate when its flags change, not when a file they
# name does, so a new profile under the old name would leave the dependencies built with
# the last one.
"$profdata" merge -o "$dir/merged.profdata" "$profiles"
rm -rf "$profiles"
# A profile with no counts would give a plain build that passes the checksums below.
counted=$("$profdata" show "$dir/merged.profdata" | sed -n 's/^Maximum function count: //p')
if [ -z "$counted" ] || [ "$counted" = 0 ]; then
  echo "the merged profile holds no counts ($dir/merged.profdata): the training did not run instrumented code" >&2
  exit 1
fi
profile="$dir/tessera-$(sha256sum "$dir/merged.profdata" | cut -c1-16).profdata"
rm -f "$dir"/tessera-*.profdata
mv "$dir/merged.profdata" "$profile"

echo "== optimised build (target dir $dir/use)" >&2
CARGO_ENCODED_RUSTFLAGS="$base-Cprofile-use=$profile" \
  "${CARGO:-cargo}" build --release --locked --bin tessera --target-dir "$dir/use" >&2
bin="$dir/use/release/tessera"

# The same bits: every training scene's checksum from the optimised binary.
for s in "${scenes[@]}"; do
  name=$(echo "$s" | tr / _)
  "$bin" bench samples "$s" --size 128x96 --spp 16 --threads 1 --runs 1 >"$work/$name.use" ||
    { echo "the optimised build failed to render $s" >&2; exit 1; }
  want=$(grep -o 'checksum [0-9a-f]*' "$work/$name.gen" || true)
  got=$(grep -o 'checksum [0-9a-f]*' "$work/$name.use" || true)
  if [ -z "$want" ] || [ "$want" != "$got" ]; then
    echo "$s: the optimised build gives image $got, the instrumented one $want" >&2
    exit 1
  fi
done
echo "== ${#scenes[@]} scenes give the same checksums; built $bin" >&2
echo "$bin"
