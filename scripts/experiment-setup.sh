# Sourced by scripts/experiment.sh and scripts/reconstruct-experiment.sh after their flags: checks
# the tools an experiment runs (messages start with $name), sets $kf (keyframer, from $KEYFRAMER)
# and $scene (the scene tool, from $KEYFRAMER_SCENE), building each when missing, and makes $work
# with an empty $results (WORK/results.jsonl).
for tool in jq colmap ffmpeg; do
  command -v "$tool" >/dev/null || { echo "$name: $tool is missing: run scripts/setup.sh" >&2; exit 1; }
done
kf="${KEYFRAMER:-target/release/keyframer}"
[ -x "$kf" ] || cargo build --release --quiet
scene="${KEYFRAMER_SCENE:-target/release/keyframer-scene}"
[ -x "$scene" ] || cargo build --release --quiet -p keyframer-scene
mkdir -p "$work"
results="$work/results.jsonl"
: > "$results"
