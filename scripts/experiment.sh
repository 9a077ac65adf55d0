#!/usr/bin/env bash
# The sampling experiment (issue 8), like the paper's table: on generated drone sequences with
# known poses, 1 fps sampling against keyframer's movement-based selection with the same number of
# keyframes (`--spacing Nkf`), each reconstructed with COLMAP and scored by `keyframer eval`
# (registered ratio, spacing of consecutive camera centres σ/Q0.1/Q0.9 after a similarity
# alignment, pose RMSE, COLMAP time). Movement-based selection runs twice: on the raw flow
# (`spacing-raw`, iVS3D's measure) and with the camera rotation subtracted (`spacing`:
# `--derotate`, with the scene's field of view). On the sequence with hovers it also compares
# `--fps 2` with and without stationary-frame removal (COLMAP time and registration).
#
#   scripts/experiment.sh [--smoke] [--seqs survey,orbit,hover-survey] [WORK]
#
# --smoke: short, small sequences (CI's version: a few dozen frames). WORK (default
# target/experiment) keeps every scene, project, export and COLMAP workspace; the table is printed
# to stdout and written to WORK/table.md, the raw numbers to WORK/results.jsonl.
# Sequences come from the workspace's scene tool: $KEYFRAMER_SCENE (default
# target/release/keyframer-scene), keyframer from $KEYFRAMER (default target/release/keyframer);
# each is built when missing.
set -euo pipefail
cd "$(dirname "$0")/.."

smoke=0
seqs="survey,orbit,hover-survey"
work=target/experiment
while [ $# -gt 0 ]; do
  case "$1" in
    --smoke) smoke=1 ;;
    --seqs) seqs="$2"; shift ;;
    -h|--help) sed -n 2,14p "$0"; exit 0 ;;
    -*) echo "experiment: unknown flag $1" >&2; exit 2 ;;
    *) work="$1" ;;
  esac
  shift
done
name=experiment
source scripts/experiment-setup.sh

scene_args=(--size 640x360)
if [ $smoke = 1 ]; then scene_args=(--size 320x180 --seconds 10 --blur-samples 2); fi

# run NAME SEQDIR SELECT-FLAGS...: select, export, COLMAP, eval; one JSON line into results.
run() {
  local name="$1" dir="$2"; shift 2
  local out="$dir/$name"
  rm -rf "$out"; mkdir -p "$out"
  "$kf" select "$dir/scene/video.mp4" -o "$out/project.json" --quiet "$@" >&2
  "$kf" export "$out/project.json" --out "$out/export" --format jpg --quiet >&2
  local k; k=$(jq -c '.intrinsics | [.fx, .fy, .cx, .cy] | map(tostring) | join(",")' -r "$dir/scene/scene.json")
  echo "experiment: $(basename "$dir") $name: $(jq '.keyframes | length' "$out/project.json") keyframes, COLMAP..." >&2
  "$kf" colmap "$out/export" -o "$out/colmap" --sparse --camera-model PINHOLE --camera-params "$k" \
    --quiet --json > "$out/colmap.json"
  "$kf" eval "$out/colmap" --gt "$dir/scene/poses.tum" --json --quiet > "$out/eval.json"
  jq -c --arg seq "$(basename "$dir")" --arg name "$name" --slurpfile c "$out/colmap.json" '{
      seq: $seq, sampling: $name, keyframes: .selected, registered: .registered,
      ratio: .registered_ratio, models: .models,
      sigma: .gt.spacing.std, q10: .gt.spacing.q10, q90: .gt.spacing.q90, mean: .gt.spacing.mean,
      gt_sigma: .gt.gt_spacing.std, rmse: .gt.position_rmse,
      colmap_s: ([$c[0].stages[].seconds] | add)
    }' "$out/eval.json" >> "$results"
}

IFS=, read -r -a seq_list <<< "$seqs"
for seq in "${seq_list[@]}"; do
  dir="$work/$seq"
  mkdir -p "$dir"
  echo "experiment: rendering $seq" >&2
  "$scene" "$dir/scene" --preset "$seq" "${scene_args[@]}" --force --quiet
  run fps1 "$dir" --fps 1
  n=$(jq '.keyframes | length' "$dir/fps1/project.json")
  hfov=$(jq '2 * ((.width / 2) / .intrinsics.fx | atan) * 180 / 3.141592653589793' "$dir/scene/scene.json")
  run spacing-raw "$dir" --spacing "${n}kf"
  run spacing "$dir" --spacing "${n}kf" --derotate --hfov "$hfov"
  if [ "$seq" = hover-survey ]; then
    run fps2 "$dir" --fps 2
    run fps2-stationary "$dir" --fps 2 --stationary
  fi
done

{
  echo "| sequence | sampling | keyframes | registered | models | σ | Q0.1 | Q0.9 | σ (GT poses) | pose RMSE | COLMAP s |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|"
  jq -r 'def r: if type == "number" then (. * 1000 | round / 1000) else "-" end;
    "| \(.seq) | \(.sampling) | \(.keyframes) | \(.registered) (\(.ratio * 100 | floor) %) | \(.models) | \(.sigma | r) | \(.q10 | r) | \(.q90 | r) | \(.gt_sigma | r) | \(.rmse | r) | \(.colmap_s * 10 | round / 10) |"' "$results"
} | tee "$work/table.md"
echo "experiment: spacing in ground-truth metres after a Sim(3) alignment; raw numbers in $results" >&2
