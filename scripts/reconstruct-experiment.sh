#!/usr/bin/env bash
# The reconstruction-in-the-loop experiment (issue 31): on keyframer-scene surveys with fast turns
# and ground truth, for each seed, plain COLMAP on uniform `--every N` selections from the
# sparsest N up (until one registers every keyframe in one model within 1 % of the path of the
# ground truth: the sparsest uniform N that reconstructs), then `keyframer reconstruct` from the sparse start `--every START`: rounds,
# frames added, final keyframes against the sparsest uniform N's, registration, the largest
# camera-centre error against the ground truth after a similarity alignment (in % of the path
# length), and the loop's COLMAP time against one COLMAP run on its final keyframes.
#
#   scripts/reconstruct-experiment.sh [--smoke] [--seeds 1,2,3] [--start 45] [--ns 60,45,30,25,20,15,10]
#                                     [--engine pycolmap|colmap] [WORK]
#
# --engine: the COLMAP that runs every sparse reconstruction, the uniform ones and the loop's
# (default pycolmap, what `reconstruct`'s `auto` takes when set-up installed it; colmap: the
# colmap command, COLMAP 3.8 on Debian).
#
# --smoke: one seed, N 30 only (the test suite's size). Every run uses the scene's intrinsics
# (PINHOLE, kept fixed), 1024 SIFT features and the loop's mapper options for plain COLMAP too
# (min_model_size=3, init_min_tri_angle=4, abs_pose_min_num_inliers=15), so that only the loop
# differs. The table goes to stdout and WORK/table.md (default WORK: target/reconstruct-experiment), raw numbers to
# WORK/results.jsonl. keyframer from $KEYFRAMER (default target/release/keyframer), the scene
# tool from $KEYFRAMER_SCENE (default target/release/keyframer-scene).
set -euo pipefail
cd "$(dirname "$0")/.."

seeds="1,2,3"
start=45
ns="60,45,30,25,20,15,10"
engine=pycolmap
work=target/reconstruct-experiment
while [ $# -gt 0 ]; do
  case "$1" in
    --smoke) seeds="1"; ns="30" ;;
    --seeds) seeds="$2"; shift ;;
    --start) start="$2"; shift ;;
    --ns) ns="$2"; shift ;;
    --engine) engine="$2"; shift ;;
    -h|--help) sed -n 2,22p "$0"; exit 0 ;;
    -*) echo "reconstruct-experiment: unknown flag $1" >&2; exit 2 ;;
    *) work="$1" ;;
  esac
  shift
done
name=reconstruct-experiment
source scripts/experiment-setup.sh
camera=(--camera-model PINHOLE --camera-params 224,224,160,90 --max-features 1024 --engine "$engine")
mapper=(--mapper-option min_model_size=3 --mapper-option init_min_tri_angle=4 --mapper-option abs_pose_min_num_inliers=15)

# Path length of the ground truth between frames A and B (poses.tum: one line per frame).
path_length() {
  awk -v a="$2" -v b="$3" 'NR-1>=a && NR-1<=b { if (n++) d += sqrt(($2-x)^2+($3-y)^2+($4-z)^2); x=$2; y=$3; z=$4 } END { print d }' "$1"
}

for seed in ${seeds//,/ }; do
  dir="$work/seed$seed"
  mkdir -p "$dir"
  if [ ! -f "$dir/scene/scene.json" ]; then
    "$scene" "$dir/scene" --force --quiet --size 320x180 --seconds 15 --blur-samples 2 --seed "$seed"
  fi
  base="$dir/base.json"
  [ -f "$base" ] || "$kf" select "$dir/scene/video.mp4" -o "$base" --spacing 10kf --blur --quiet
  sparsest=""
  for n in ${ns//,/ }; do
    out="$dir/every$n"
    rm -rf "$out"; mkdir -p "$out"
    # Beside base.json: a project's input path is relative to its folder, so a copy elsewhere
    # would not find its cache (the movement series the loop's repairs are placed by).
    project="$dir/every$n.json"
    cp "$base" "$project"
    "$kf" select "$dir/scene/video.mp4" -o "$project" --every "$n" --force --quiet
    "$kf" export "$project" --out "$out/export" --quiet
    echo "reconstruct-experiment: seed $seed every $n: plain COLMAP..." >&2
    "$kf" colmap "$out/export" -o "$out/colmap" --sparse "${camera[@]}" "${mapper[@]}" --quiet --json \
      > "$out/colmap.json" 2>/dev/null || true
    frames=$(jq '.keyframes | length' "$project")
    largest=$(jq '[.models[].registered_images] | max // 0' "$out/colmap.json" 2>/dev/null || echo 0)
    models=$(jq '.models | length' "$out/colmap.json" 2>/dev/null || echo 0)
    secs=$(jq '[.stages[].seconds] | add' "$out/colmap.json" 2>/dev/null || echo 0)
    # A model in one piece can still be wrong (docs/reconstruct.md, "A mis-assembled model").
    pct=null
    if [ "$largest" = "$frames" ] && "$kf" eval "$out/colmap" --gt "$dir/scene/poses.tum" --json --quiet > "$out/eval.json" 2>/dev/null; then
      length=$(path_length "$dir/scene/poses.tum" "$(jq '.keyframes[0]' "$project")" "$(jq '.keyframes[-1]' "$project")")
      pct=$(jq --argjson length "$length" '100 * .gt.position_max / $length' "$out/eval.json")
    fi
    jq -cn --arg seed "$seed" --arg n "$n" --argjson frames "$frames" --argjson largest "$largest" \
      --argjson models "$models" --argjson secs "$secs" --argjson pct "$pct" \
      '{seed: $seed, run: ("every " + $n), frames: $frames, registered: $largest, models: $models, colmap_s: $secs, max_error_pct: $pct}' >> "$results"
    # One piece as the loop counts it (the largest model registers every keyframe; a further
    # model can only hold images registered twice), and right: within 1 % of the path.
    if [ "$pct" != null ] && jq -en --argjson pct "$pct" '$pct <= 1' >/dev/null; then
      sparsest="$n"; sparsest_frames="$frames"; break
    fi
  done
  out="$dir/loop"
  rm -rf "$out"; mkdir -p "$out"
  start_project="$dir/loop-start.json"
  cp "$base" "$start_project"
  "$kf" select "$dir/scene/video.mp4" -o "$start_project" --every "$start" --force --quiet
  echo "reconstruct-experiment: seed $seed: reconstruct from every $start..." >&2
  "$kf" reconstruct "$start_project" --out "$out/ws" "${camera[@]}" --json > "$out/summary.json" \
    2> "$out/reconstruct.log"
  "$kf" eval "$out/ws/colmap" --gt "$dir/scene/poses.tum" --json --quiet > "$out/eval.json" || echo '{}' > "$out/eval.json"
  first=$(jq '.final_keyframes[0]' "$out/summary.json")
  last=$(jq '.final_keyframes[-1]' "$out/summary.json")
  length=$(path_length "$dir/scene/poses.tum" "$first" "$last")
  "$kf" colmap "$out/ws" -o "$out/once" --sparse "${camera[@]}" "${mapper[@]}" --quiet --json > "$out/once.json" 2>/dev/null || true
  once=$(jq '[.stages[].seconds] | add' "$out/once.json" 2>/dev/null || echo 0)
  once_cpu=$(jq '[.stages[].cpu_s] | add' "$out/once.json" 2>/dev/null || echo 0)
  jq -c --arg seed "$seed" --arg start "$start" --arg sparsest "${sparsest:-none}" \
    --argjson sparsest_frames "${sparsest_frames:-0}" --argjson length "$length" --argjson once "$once" --argjson once_cpu "$once_cpu" \
    --slurpfile e "$out/eval.json" '{seed: $seed, run: ("reconstruct from every " + $start),
      start: .start_keyframes, frames: (.final_keyframes | length), registered, models: (.models | length),
      rounds, outcome, colmap_s: .colmap_total_s, once_s: $once,
      colmap_cpu_s: .colmap_cpu_s, once_cpu_s: $once_cpu,
      max_error_pct: (if $e[0].gt then 100 * $e[0].gt.position_max / $length else null end),
      sparsest_uniform: $sparsest, sparsest_frames: $sparsest_frames}' "$out/summary.json" >> "$results"
done

{
  echo "| seed | run | keyframes | registered (largest model) | models | rounds | COLMAP s | one run on final set s | loop ÷ one run, CPU | max GT error % of path | sparsest uniform N (frames) |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|"
  jq -r '"| \(.seed) | \(.run) | \(if .start then "\(.start) → \(.frames)" else .frames end) | \(.registered) | \(.models) | \(.rounds // "-") | \(.colmap_s * 10 | round / 10) | \(if .once_s then (.once_s * 10 | round / 10) else "-" end) | \(if .once_cpu_s and .once_cpu_s > 0 then (.colmap_cpu_s / .once_cpu_s * 100 | round / 100) else "-" end) | \(if .max_error_pct then (.max_error_pct * 100 | round / 100) else "-" end) | \(if .sparsest_uniform then "\(.sparsest_uniform) (\(.sparsest_frames))" else "-" end) |"' "$results"
} | tee "$work/table.md"
