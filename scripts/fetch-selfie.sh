#!/usr/bin/env bash
# Fetches a person-segmentation model for `export --masks models/selfie.toml`: MediaPipe's selfie
# segmentation (Apache-2.0, Google) as the npm registry's @mediapipe/selfie_segmentation package
# ships it (TFLite; pinned version, sha256 checked), converted to ONNX by scripts/tflite-onnx.py
# (Python standard library only; the conversion is deterministic, so the ONNX files' sha256 are
# pinned too). Usage: scripts/fetch-selfie.sh [DIR] (default target/models/selfie); prints DIR.
# Safe to run again: nothing is fetched while DIR holds both files with the pinned checksums.
set -euo pipefail
version=0.1.1675465747
package_sha256=7767b33eaa68990ee06c28bbb89f39a13a47ebb07ff0f1fd4947d9e817bb9bf9
onnx_sha256="17ff5ae06e16dd6ddf0b8c5c4ae2a839edcaaabae452ae6cd0b620d85572693b  selfie_segmentation.onnx
fc099fddf727b141e75d78966afd5b6c192a5923ede5051d2b1bdb01bdba00a0  selfie_segmentation_landscape.onnx"
dest="${1:-target/models/selfie}"
if (cd "$dest" 2>/dev/null && sha256sum -c --status - <<<"$onnx_sha256"); then echo "$dest"; exit 0; fi
echo "fetch-selfie: fetching @mediapipe/selfie_segmentation $version (npm) into $dest" >&2
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
url="https://registry.npmjs.org/@mediapipe/selfie_segmentation/-/selfie_segmentation-$version.tgz"
curl -fsSL --retry 3 -o "$tmp/package.tgz" "$url"
echo "$package_sha256  $tmp/package.tgz" | sha256sum -c --quiet -
tar -xzf "$tmp/package.tgz" -C "$tmp" package/selfie_segmentation.tflite \
  package/selfie_segmentation_landscape.tflite
for m in selfie_segmentation selfie_segmentation_landscape; do
  python3 "$(dirname "$0")/tflite-onnx.py" "$tmp/package/$m.tflite" "$tmp/$m.onnx"
done
if ! (cd "$tmp" && sha256sum -c --quiet - <<<"$onnx_sha256"); then
  echo "fetch-selfie: the converted ONNX files differ from the pinned ones (was scripts/tflite-onnx.py changed? then verify its output and pin the new sha256)" >&2
  exit 1
fi
cat >"$tmp/SOURCE.txt" <<EOF
MediaPipe selfie segmentation (Copyright Google LLC, Apache License 2.0:
https://www.apache.org/licenses/LICENSE-2.0), from the npm package
@mediapipe/selfie_segmentation $version (sha256 $package_sha256),
converted from TFLite to ONNX (opset 17) by keyframer's scripts/tflite-onnx.py.
EOF
mkdir -p "$dest"
mv "$tmp"/*.onnx "$tmp/SOURCE.txt" "$dest/"
echo "$dest"
