#!/usr/bin/env bash
# Fetches ONNX Runtime's shared library (x86_64 Linux) from the PyPI onnxruntime wheel (Debian has
# no package) for `--mask-backend ort`. Usage: scripts/fetch-ort.sh [DIR]; prints the library's
# path. Point keyframer at it with ORT_DYLIB_PATH=<that path>. Safe to run again.
set -euo pipefail
version="${ORT_VERSION:-1.31.1}"
dest="${1:-target/onnxruntime}"
lib="$dest/libonnxruntime.so.$version"
if [ -s "$lib" ]; then echo "$lib"; exit 0; fi
mkdir -p "$dest"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
# Any cp3xx manylinux x86_64 wheel carries the same library; take the first listed.
url="$(curl -fsSL --retry 3 https://pypi.org/simple/onnxruntime/ \
  | grep -o "https://[^\"]*/onnxruntime-$version-cp3[0-9]*-cp3[0-9]*-manylinux[^\"]*x86_64\.whl#sha256=[0-9a-f]*" \
  | head -n1)" || true
if [ -z "$url" ]; then
  echo "fetch-ort: no manylinux x86_64 wheel for onnxruntime $version on PyPI" >&2
  exit 1
fi
wheel="$tmp/$(basename "${url%%#*}")"
curl -fsSL --retry 3 -o "$wheel" "${url%%#*}"
echo "${url##*sha256=}  $wheel" | sha256sum -c --quiet -
unzip -q -o -j "$wheel" "onnxruntime/capi/libonnxruntime.so.$version" -d "$tmp/lib"
mv "$tmp/lib/libonnxruntime.so.$version" "$lib"
echo "$lib"
