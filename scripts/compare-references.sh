#!/usr/bin/env bash
# Renders the benchmark scenes (scenes/spheres.toml, scenes/cornell.toml and, once
# `python3 scenes/generate-terrain.py` has written its mesh, the 1M-triangle
# scenes/terrain/terrain.toml at 320x240) at SPP samples per pixel with two seeds, compares each with
# Mitsuba 3's converged `cook` reference, and prints:
#   rmse      error of our image against the reference (linear RGB, all pixels/channels)
#   noise     our own noise: rmse between our two seeds / sqrt(2)
#   ref noise the reference's own noise, as measured with the references
#   bias      sqrt(max(0, rmse^2 - noise^2 - ref_noise^2)): what noise does not explain
#   rmse[0,1] the rmse with both images clamped to [0, 1], as a display shows them (a few
#             pixels seeing the light, at radiance 200, otherwise dominate the rmse)
# Usage: scripts/compare-references.sh [SPP [RENDER ARGS...]] (default 256); RENDER ARGS go
# to every `tessera render`, e.g. `4096 --noise 0.1` checks adaptive sampling (SPP then the
# most a pixel takes) for bias. SCENES=spheres,cornell limits the scenes. The references are in
# docs/references (or REFS=path/to/refs). BIN=path/to/tessera uses that build instead of
# building target/release/tessera (e.g. to compare two builds, docs/determinism.md).
set -euo pipefail
cd "$(dirname "$0")/.."
spp=${1:-256}
shift || true
extra=("$@")
refs=${REFS:-docs/references}
if [ -z "${BIN:-}" ]; then
  cargo build --release --quiet
fi
bin=${BIN:-target/release/tessera}
tmp=$(mktemp -d)
seeded=
trap 'rm -rf "$tmp"; [ -z "$seeded" ] || rm -f "$seeded"' EXIT
printf '%-8s %5s %10s %10s %10s %10s %10s\n' scene spp rmse noise "ref noise" bias "rmse[0,1]"
for scene in $(tr , " " <<< "${SCENES:-spheres,cornell,terrain}"); do
  file=scenes/$scene.toml size=()
  case $scene in
    spheres) ref_noise=0.00976 ;;
    cornell) ref_noise=0.00086 ;;
    terrain) ref_noise=0.00019 file=scenes/terrain/terrain.toml size=(--size 320x240)
      if [ ! -f scenes/terrain/terrain.obj ]; then
        echo "terrain: skipped (run python3 scenes/generate-terrain.py to write its mesh)"
        continue
      fi ;;
    *) echo "SCENES: no reference for '$scene' (spheres, cornell, terrain)" >&2; exit 2 ;;
  esac
  for seed in 1 2; do
    # Beside the original, so that the paths of its assets resolve.
    seeded=$(mktemp "$(dirname "$file")/.seed$seed-XXXXXX.toml")
    sed "s/^\[render\]\$/[render]\nseed = $seed/" "$file" > "$seeded"
    grep -q "^seed = $seed\$" "$seeded" || { echo "$file: no [render] table to set the seed in" >&2; exit 1; }
    "$bin" render "$seeded" -o "$tmp/$scene-$seed.exr" --spp "$spp" ${size[@]+"${size[@]}"} ${extra[@]+"${extra[@]}"} 2>/dev/null
    rm -f "$seeded"
    seeded=
  done
  rmse=$("$bin" compare "$tmp/$scene-1.exr" "$refs/${scene}_cook.exr" | awk '{print $2}')
  between=$("$bin" compare "$tmp/$scene-1.exr" "$tmp/$scene-2.exr" | awk '{print $2}')
  clamped=$("$bin" compare "$tmp/$scene-1.exr" "$refs/${scene}_cook.exr" --clamp 1 | awk '{print $2}')
  awk -v s="$scene" -v n="$spp" -v r="$rmse" -v b="$between" -v rn="$ref_noise" -v c="$clamped" 'BEGIN {
    noise = b / sqrt(2); bias2 = r * r - noise * noise - rn * rn; if (bias2 < 0) bias2 = 0;
    printf "%-8s %5d %10.5f %10.5f %10.5f %10.5f %10.5f\n", s, n, r, noise, rn, sqrt(bias2), c }'
done
