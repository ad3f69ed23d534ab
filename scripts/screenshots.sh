#!/usr/bin/env bash
# Re-make docs/screenshots/<scenario>.png: run every built-in scenario, open each recording in
# the Rerun viewer (the one that ships in rerun-sdk) on a virtual display, save a screenshot.
#
# Needs Debian's xvfb and mesa-vulkan-drivers (the viewer renders through Mesa's Vulkan
# software rasteriser, lavapipe) and xdotool (to park the pointer outside the window, where
# it shows no hover tooltip); installs them with apt-get if missing. Run from anywhere:
#   bash scripts/screenshots.sh [SCENARIO ...]
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
for pkg in xvfb mesa-vulkan-drivers xdotool; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
  sudo_cmd=""
  [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "${missing[@]}" >/dev/null
fi

out_dir="docs/screenshots"
rec_dir="$(mktemp -d)"
mkdir -p "$out_dir"
if [ $# -gt 0 ]; then
  scenarios=("$@")
else
  mapfile -t scenarios < <(.venv/bin/vnav-demo list | awk '{print $1}')
fi

display=":$((90 + RANDOM % 100))"
Xvfb "$display" -screen 0 1600x1000x24 >/dev/null 2>&1 &
xvfb_pid=$!
trap 'kill $xvfb_pid 2>/dev/null; rm -rf "$rec_dir"' EXIT
sleep 1
DISPLAY="$display" xdotool mousemove 1599 999

for name in "${scenarios[@]}"; do
  .venv/bin/vnav-demo run "$name" --out "$rec_dir" --quiet || true
  DISPLAY="$display" timeout 300 .venv/bin/rerun --port auto --window-size 1400x900 \
    --screenshot-to "$out_dir/$name.png" "$rec_dir/$name.rrd" >/dev/null 2>&1
  echo "wrote $out_dir/$name.png"
done
