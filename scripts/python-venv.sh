#!/usr/bin/env bash
# Makes (or reuses) a Python virtual environment for a test's tools and prints its path.
#   Usage: scripts/python-venv.sh NAME REQUIREMENTS
# The venv lives in ${CARGO_TARGET_DIR:-<repo>/target}/python/NAME and is rebuilt when the
# requirements file changes (its hash is kept beside the venv). Exits non-zero, saying why
# on stderr, when Python, its venv module or the package index cannot be had: the tests
# that call it then skip.
set -euo pipefail
if [ $# -ne 2 ]; then
  echo "usage: $0 NAME REQUIREMENTS" >&2
  exit 2
fi
name=$1
requirements=$2
root=$(cd "$(dirname "$0")/.." && pwd)
[ -f "$requirements" ] || { echo "no requirements file $requirements" >&2; exit 2; }
python=${PYTHON:-python3}
command -v "$python" >/dev/null || { echo "no $python on PATH" >&2; exit 3; }
"$python" -c 'import venv, ensurepip' 2>/dev/null \
  || { echo "$python has no venv/ensurepip module (Debian: apt-get install python3-venv)" >&2; exit 3; }
venv=${CARGO_TARGET_DIR:-$root/target}/python/$name
stamp=$venv/.requirements.sha256
want=$(sha256sum "$requirements" | cut -d' ' -f1)
# Two tests may ask for the same venv at once: one builds it, the other waits.
mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
flock 9
if [ -x "$venv/bin/python" ] && [ "$(cat "$stamp" 2>/dev/null)" = "$want" ]; then
  echo "$venv"
  exit 0
fi
rm -rf "$venv"
"$python" -m venv "$venv" >&2
if ! "$venv/bin/python" -m pip install --disable-pip-version-check -q -r "$requirements" >&2; then
  rm -rf "$venv"
  echo "pip could not install $requirements (is the package index reachable?)" >&2
  exit 4
fi
echo "$want" >"$stamp"
echo "$venv"
