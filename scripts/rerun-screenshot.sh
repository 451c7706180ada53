#!/usr/bin/env bash
# Open a recording in the real rerun viewer on a virtual screen (Xvfb, Mesa's software Vulkan) and save
# what it shows as a PNG: the README's screenshot comes from here.
#   scripts/rerun-screenshot.sh FILE.rrd OUT.png [WIDTHxHEIGHT]
# rerun's own --headless mode loads no file before its screenshot (0.41), hence the virtual screen.
set -euo pipefail
rrd=${1:?usage: $0 FILE.rrd OUT.png [WIDTHxHEIGHT]}
out=${2:?usage: $0 FILE.rrd OUT.png [WIDTHxHEIGHT]}
size=${3:-1600x900}
here=$(cd "$(dirname "$0")/.." && pwd)
"$here/scripts/install-debs.sh" xvfb mesa-vulkan-drivers
display=:$((90 + RANDOM % 100))
# X starts the pointer at the screen's centre; on a screen twice the window's size (the window opens at the
# top-left corner) that is outside the window, so no hover tooltip lands in the middle of the picture.
w=${size%x*} h=${size#*x}
Xvfb "$display" -screen 0 "$((2 * w + 64))x$((2 * h + 64))x24" >/dev/null 2>&1 &
xvfb=$!
trap 'kill $xvfb 2>/dev/null || true' EXIT
sleep 1
port=$("$here/.venv/bin/python" -c "from sync.zenoh_transport import free_port; print(free_port())")
runtime=$(mktemp -d)
DISPLAY=$display XDG_RUNTIME_DIR=$runtime "$here/.venv/bin/rerun" --port "$port" --window-size "$size" \
  --screenshot-to "$out" "$rrd" >/dev/null 2>&1
rm -rf "$runtime"
echo "wrote $out"
