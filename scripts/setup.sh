#!/usr/bin/env bash
# Installs what keyframer needs on Debian 12 (only what is missing), fetches the public test data
# (Debian's opencv-doc examples) into target/testdata/, ONNX Runtime into target/onnxruntime/ and
# a person-segmentation model into target/models/selfie/ and pycolmap (a recent COLMAP, for
# rig-aware mapping of 360° rig exports) into target/pycolmap/. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(libopencv-dev clang libclang-dev mesa-vulkan-drivers libvulkan1 ffmpeg pkg-config ca-certificates curl unzip colmap chromium jq fonts-dejavu-core libimage-exiftool-perl sqlite3 python3 python3-venv)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}" >&2
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

if ! command -v cargo >/dev/null; then
  echo "setup: cargo not found; install Rust from https://rustup.rs" >&2
  exit 1
fi

# Public test data: Debian's opencv-doc examples (vtest.avi, Megamind_bugy.avi, blur images,
# Middlebury pairs). Not committed; unpacked here once.
data=target/testdata
if [ ! -f "$data/opencv-doc/.complete" ]; then
  echo "setup: fetching Debian's opencv-doc test data into $data" >&2
  mkdir -p "$data/download"
  (cd "$data/download" && rm -f opencv-doc_*.deb && apt-get download -q opencv-doc >/dev/null)
  rm -rf "$data/opencv-doc.tmp"
  dpkg -x "$data"/download/opencv-doc_*.deb "$data/opencv-doc.tmp"
  rm -rf "$data/opencv-doc"
  mkdir -p "$data/opencv-doc"
  mv "$data/opencv-doc.tmp/usr/share/doc/opencv-doc/examples/data/"* "$data/opencv-doc/"
  rm -rf "$data/opencv-doc.tmp" "$data/download"
  touch "$data/opencv-doc/.complete"
fi

# ONNX Runtime for `--mask-backend ort` (Debian has no package): the library from PyPI's wheel.
if [ ! -s target/onnxruntime/libonnxruntime.so.1.31.1 ]; then
  echo "setup: fetching ONNX Runtime 1.31.1 into target/onnxruntime/" >&2
  scripts/fetch-ort.sh target/onnxruntime >/dev/null
fi

# A person-segmentation model for `export --masks models/selfie.toml`: MediaPipe's selfie
# segmentation (Apache-2.0) from the npm registry's package, converted to ONNX (4 MB download).
scripts/fetch-selfie.sh target/models/selfie >/dev/null

# pycolmap for `keyframer colmap --engine pycolmap` (rigs; Debian's COLMAP 3.8 has none): a venv
# with PyPI's CPU wheel, version pinned. keyframer finds target/pycolmap/bin/python beside
# target/release/.
pycolmap_version=4.2.1
if ! target/pycolmap/bin/python -c "import pycolmap, sys; sys.exit(pycolmap.__version__ != '$pycolmap_version')" 2>/dev/null; then
  echo "setup: installing pycolmap $pycolmap_version into target/pycolmap/" >&2
  rm -rf target/pycolmap
  if ! { python3 -m venv target/pycolmap &&
         target/pycolmap/bin/pip install -q --disable-pip-version-check "pycolmap==$pycolmap_version"; }; then
    rm -rf target/pycolmap
    echo "setup: could not install pycolmap $pycolmap_version into target/pycolmap (python3 -m venv, then pip install from PyPI); keyframer colmap --engine pycolmap needs it" >&2
    exit 1
  fi
fi
