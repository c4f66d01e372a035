#!/usr/bin/env bash
# Takes the README's screenshots of the desktop viewer under Xvfb: a standalone
# coordinator, one worker thread, the spheres scene at 64 spp, captured at about 1 %, 5 %
# and 100 %. There is no window manager (twm made xwd hang here), so the window's title
# bar, which carries the status line, is not in the pictures; the script prints it.
# Needs: apt-get install xvfb x11-apps imagemagick. Usage: scripts/viewer-screenshots.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
bin=$PWD/target/release/tessera
export DISPLAY=:77
Xvfb "$DISPLAY" -screen 0 700x460x24 >/dev/null 2>&1 &
xvfb=$!
tmpd=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$tmpd"' EXIT
sleep 1
"$bin" coordinator --listen 127.0.0.1:7901 2>/dev/null &
sleep 0.5
url=http://127.0.0.1:7901
"$bin" submit scenes/spheres.toml --coordinator "$url" --spp 64 >/dev/null
"$bin" view --coordinator "$url" --job 1 &
sleep 1.5
RUST_LOG=warn "$bin" worker --coordinator "$url" --threads 1 &
percent() { "$bin" status --coordinator "$url" | awk '$1 == "1" { for (i = 1; i <= NF; i++) if ($i ~ /%$/) { sub("%", "", $i); print $i } }'; }
shoot() { # wait until the job passes $1 percent, then capture the screen
  until awk -v p="$(percent)" -v want="$1" 'BEGIN { exit !(p + 0 >= want) }'; do sleep 0.02; done
  sleep 0.05
  xwd -root -silent > "$tmpd/shot.xwd" 2>"$tmpd/err" || { cat "$tmpd/err"; exit 1; }
  /usr/bin/convert "$tmpd/shot.xwd" "docs/images/viewer-$2.png" || { echo "convert failed"; ls -la "$tmpd"; exit 1; }
  echo "captured at $(percent)%: $("$bin" status --coordinator "$url" | awk '$1 == "1"')"
}
shoot 0.5 01
shoot 4 05
until "$bin" status --coordinator "$url" | grep -q ' done '; do sleep 0.2; done
sleep 1
xwd -root -silent > "$tmpd/shot.xwd"
/usr/bin/convert "$tmpd/shot.xwd" docs/images/viewer-100.png
echo "captured at 100%"
