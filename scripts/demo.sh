#!/usr/bin/env bash
# README command (1): set up, build, make a sample clip, select keyframes and export them.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
cargo build --release --locked
kf=target/release/keyframer
out=target/demo
rm -rf "$out"
mkdir -p "$out"
echo "demo: making a 10 s 640x360 sample clip (ffmpeg testsrc2)" >&2
ffmpeg -loglevel error -f lavfi -i testsrc2=size=640x360:rate=30:duration=10 \
  -c:v libx264 -pix_fmt yuv420p "$out/sample.mp4"
"$kf" info
"$kf" probe "$out/sample.mp4"
"$kf" select "$out/sample.mp4" --fps 2 --blur --blur-mode replace --blur-window 3 -o "$out/sample.kf.json"
"$kf" export "$out/sample.kf.json" --out "$out/keyframes" --resize 320x180
echo
echo "demo: project file:  $out/sample.kf.json"
echo "demo: keyframes:     $out/keyframes/images/ ($(ls "$out/keyframes/images" | grep -c '\.jpg$') images), $out/keyframes/manifest.json"
