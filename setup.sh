#!/usr/bin/env bash
# Sets up vnav-sim on a fresh Debian/Ubuntu machine: the system libraries MuJoCo needs to render
# off-screen (EGL through Mesa), a virtual environment in .venv, and the project with its test
# and sweep extras (the tests run sweeps on Ray for real). Safe to run again: it skips what is
# already there.
set -euo pipefail
cd "$(dirname "$0")"

need_pkgs=()
for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri libglx-mesa0; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need_pkgs+=("$pkg")
done
if [ ${#need_pkgs[@]} -gt 0 ]; then
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup.sh: missing system packages (${need_pkgs[*]}) and no apt-get to install them" >&2
    exit 1
  fi
  sudo_cmd=""
  [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
  echo "setup.sh: installing ${need_pkgs[*]}" >&2
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "${need_pkgs[@]}" >/dev/null
fi

python_bin="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$python_bin" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test,sweep]'
