#!/usr/bin/env bash
# README command (2): set up, then run the whole test suite (formatting, lints, tests).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
export KEYFRAMER_TESTDATA="$PWD/target/testdata"
export ORT_DYLIB_PATH="${ORT_DYLIB_PATH:-$PWD/target/onnxruntime/libonnxruntime.so.1.31.1}"
cargo fmt --all -- --check
cargo clippy --locked --release --workspace --all-targets -- -D warnings
# The library without OpenCV, as keyframer-gpu-bench builds it (a subset: ~20 s more).
cargo clippy --locked --release -p keyframer -p keyframer-gpu-bench --no-default-features --all-targets -- -D warnings
cargo test --locked --release --workspace
