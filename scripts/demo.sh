#!/usr/bin/env bash
# README command (1): set up, build, then the real job on a synthetic drone flight: render the
# flight with its DJI-style telemetry (video.SRT), select keyframes by ground-footprint overlap
# and sharpness, export them (geotagged), reconstruct them with COLMAP when it is installed, and
# write the report with the camera path and the flight map.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
cargo build --release --locked --workspace
kf=target/release/keyframer
out=target/demo
rm -rf "$out"
mkdir -p "$out"
echo "demo: rendering a 30 s synthetic drone survey (640x360, 30 fps) with its telemetry" >&2
target/release/keyframer-scene "$out/flight" --seconds 30
"$kf" info
"$kf" probe "$out/flight/video.mp4"
# The telemetry sidecar (flight/video.SRT) is found beside the video.
"$kf" select "$out/flight/video.mp4" --footprint-overlap 80 --blur -o "$out/flight.kf.json"
"$kf" export "$out/flight.kf.json" --out "$out/keyframes"
model=()
if command -v colmap >/dev/null; then
  "$kf" colmap "$out/keyframes" --sparse
  model=(--model "$out/keyframes/colmap")
else
  echo "demo: colmap is not installed: no reconstruction, no camera path in the report" >&2
fi
"$kf" report "$out/flight.kf.json" -o "$out/report.html" --export "$out/keyframes" "${model[@]}"
echo
echo "demo: project file:  $out/flight.kf.json"
echo "demo: keyframes:     $out/keyframes/images/ ($(ls "$out/keyframes/images" | grep -c '\.jpg$') images), $out/keyframes/manifest.json"
first=$(ls "$out/keyframes/images" | head -n 1)
if command -v exiftool >/dev/null; then
  echo "demo: geotag of $first: $(exiftool -s3 -n -GPSLatitude -GPSLongitude -GPSAltitude "$out/keyframes/images/$first" | tr '\n' ' ')"
fi
[ ${#model[@]} -eq 0 ] || echo "demo: COLMAP model:   $out/keyframes/colmap/sparse/0"
echo "demo: report:        $out/report.html (timeline, keyframes, steps, camera path, flight map)"
