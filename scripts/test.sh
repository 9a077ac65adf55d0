#!/usr/bin/env bash
# README command (2): set up, then run the whole test suite (formatting, lints, tests).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
export KEYFRAMER_TESTDATA="$PWD/target/testdata"
cargo fmt --all -- --check
cargo clippy --locked --release --all-targets -- -D warnings
cargo test --locked --release
