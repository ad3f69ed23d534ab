#!/usr/bin/env bash
# Re-make docs/screenshots/<scenario>.png: run every built-in scenario, open each recording in
# the Rerun viewer (the one that ships in rerun-sdk) on a virtual display and take its picture
# at the instant the recording's 3D views are framed for (the scenario's show_at_s, else its
# end): scripts/screenshot.py.
#
# Needs Debian's xvfb and mesa-vulkan-drivers (the viewer renders through Mesa's Vulkan
# software rasteriser, lavapipe) and xclip (the picture comes by the clipboard); installs them
# with apt-get if missing. The virtual screen is larger than the window so that its pointer,
# parked at the screen's centre, lies outside the viewer and shows no hover tooltip. Run from
# anywhere:
#   bash scripts/screenshots.sh [SCENARIO ...]
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
for pkg in xvfb mesa-vulkan-drivers xclip; do
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
  mapfile -t scenarios < <(.venv/bin/python -c \
    'from scenarios.scenario import builtin; print("\n".join(builtin.names()))')
fi

display=":$((90 + RANDOM % 100))"
# The viewer draws at 2 physical pixels per point and Xvfb's pointer rests at the screen's
# centre: at 6000x4000 that centre is (1500, 1000) points, outside the 1400x900 window, so
# no hover tooltip is drawn over the picture.
Xvfb "$display" -screen 0 6000x4000x24 >/dev/null 2>&1 &
xvfb_pid=$!
trap 'kill $xvfb_pid 2>/dev/null; rm -rf "$rec_dir"' EXIT
sleep 1


for name in "${scenarios[@]}"; do
  rc=0
  .venv/bin/vnav-demo run "$name" --out "$rec_dir" --quiet || rc=$?
  if [ "$rc" -gt 1 ]; then  # 1: a check failed, still worth a look; more: no recording
    echo "screenshots.sh: vnav-demo run $name failed (exit $rc)" >&2
    exit 1
  fi
  DISPLAY="$display" timeout 600 .venv/bin/python scripts/screenshot.py \
    "$rec_dir/$name.rrd" "$out_dir/$name.png"
  echo "wrote $out_dir/$name.png"
done
