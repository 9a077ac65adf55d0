#!/usr/bin/env bash
# Incremental against global mapping on the same sequence (issue 31, "Engines"): on keyframer-scene
# surveys with fast turns and ground truth (the scenes of scripts/reconstruct-experiment.sh), for
# each seed and each uniform `--every N`, one `keyframer colmap --sparse` (Debian's COLMAP 3.8:
# features, sequential matching, its incremental mapper), then on copies of that same database
# pycolmap's incremental mapper and its global mapper (GLOMAP, `pycolmap.global_mapping`; COLMAP
# 3.12 and later have it as `colmap global_mapper`). Each model: seconds, registered images of the
# largest model, models, and the largest camera-centre error against the ground truth after a
# similarity alignment, in % of the path length (`keyframer eval --gt`).
#
#   scripts/mapper-compare.sh [--seeds 1,2,3] [--ns 30,15,5] [WORK]
#
# pycolmap: the Python from $PYCOLMAP_PYTHON, else a virtual environment made in WORK/venv with
# `pip install pycolmap==4.2.1` (needs the network once). The table goes to stdout and
# WORK/table.md (default WORK: target/mapper-compare), raw numbers to WORK/results.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."

seeds="1,2,3"
ns="30,15,5"
work=target/mapper-compare
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds="$2"; shift ;;
    --ns) ns="$2"; shift ;;
    -h|--help) sed -n 2,15p "$0"; exit 0 ;;
    -*) echo "mapper-compare: unknown flag $1" >&2; exit 2 ;;
    *) work="$1" ;;
  esac
  shift
done
name=mapper-compare
source scripts/experiment-setup.sh
camera=(--camera-model PINHOLE --camera-params 224,224,160,90 --max-features 1024)
mapper=(--mapper-option min_model_size=3 --mapper-option init_min_tri_angle=4)

py="${PYCOLMAP_PYTHON:-}"
if [ -z "$py" ]; then
  py="$work/venv/bin/python"
  if ! "$py" -c 'import pycolmap' 2>/dev/null; then
    python3 -m venv "$work/venv"
    "$work/venv/bin/pip" install --quiet pycolmap==4.2.1
  fi
fi
"$py" -c 'import pycolmap' || { echo "mapper-compare: no pycolmap in $py" >&2; exit 1; }

# Maps DATABASE's images (in IMAGES) with pycolmap's ENGINE into OUT/0, 1, ...; prints the seconds.
map_with() {
  "$py" - "$@" <<'PY'
import os, sys, time, pycolmap
engine, db, images, out = sys.argv[1:5]
os.makedirs(out, exist_ok=True)
# The options keyframer gives COLMAP 3.8's mapper: known intrinsics kept fixed, models of 3
# images and up, a 4 degree initial triangulation angle (the global mapper has no initial pair).
if engine == "incremental":
    o = pycolmap.IncrementalPipelineOptions()
    o.min_model_size = 3
    o.mapper.init_min_tri_angle = 4
    o.ba_refine_focal_length = False
    o.ba_refine_extra_params = False
    t = time.monotonic()
    pycolmap.incremental_mapping(db, images, out, o)
else:
    o = pycolmap.GlobalPipelineOptions()
    o.min_model_size = 3
    o.mapper.bundle_adjustment.refine_focal_length = False
    o.mapper.bundle_adjustment.refine_extra_params = False
    t = time.monotonic()
    pycolmap.global_mapping(db, images, out, o)
print(f"{time.monotonic() - t:.2f}")
PY
}

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
  for n in ${ns//,/ }; do
    out="$dir/every$n"
    rm -rf "$out"; mkdir -p "$out"
    "$kf" select "$dir/scene/video.mp4" -o "$out/project.json" --every "$n" --quiet
    "$kf" export "$out/project.json" --out "$out/export" --quiet
    echo "mapper-compare: seed $seed every $n: COLMAP 3.8..." >&2
    "$kf" colmap "$out/export" -o "$out/colmap" --sparse "${camera[@]}" "${mapper[@]}" --quiet --json \
      > "$out/colmap.json" 2>/dev/null || true
    frames=$(jq '.keyframes | length' "$out/project.json")
    length=$(path_length "$dir/scene/poses.tum" "$(jq '.keyframes[0]' "$out/project.json")" "$(jq '.keyframes[-1]' "$out/project.json")")
    mapper_s=$(jq '[.stages[] | select(.stage == "mapper") | .seconds] | add // 0' "$out/colmap.json" 2>/dev/null || echo 0)
    for engine in colmap3.8-incremental pycolmap-incremental pycolmap-global; do
      model="$out/colmap/sparse"
      secs="$mapper_s"
      if [ "$engine" != colmap3.8-incremental ]; then
        kind="${engine#pycolmap-}"
        cp "$out/colmap/database.db" "$out/$kind.db"
        echo "mapper-compare: seed $seed every $n: pycolmap $kind..." >&2
        secs=$(map_with "$kind" "$out/$kind.db" "$out/colmap/images" "$out/$kind" 2>"$out/$kind.log" | tail -1) || secs=null
        model="$out/$kind"
      fi
      e="$out/eval-$engine.json"
      "$kf" eval "$model" --export "$out/export" --gt "$dir/scene/poses.tum" --json --quiet > "$e" 2>/dev/null || echo '{}' > "$e"
      jq -c --arg seed "$seed" --arg n "$n" --arg engine "$engine" --argjson frames "$frames" \
        --argjson secs "${secs:-null}" --argjson length "$length" '{seed: $seed, every: $n, frames: $frames,
          engine: $engine, mapper_s: $secs, registered: (.registered // 0),
          models: (.models // 0),
          max_error_pct: (if .gt then 100 * .gt.position_max / $length else null end)}' "$e" >> "$results"
    done
  done
done

{
  echo "| seed | every N (frames) | engine | mapping s | registered (largest model) | models | max GT error % of path |"
  echo "|---|---|---|---|---|---|---|"
  jq -r '"| \(.seed) | \(.every) (\(.frames)) | \(.engine) | \(if .mapper_s then (.mapper_s * 100 | round / 100) else "-" end) | \(.registered) | \(.models) | \(if .max_error_pct then (.max_error_pct * 100 | round / 100) else "-" end) |"' "$results"
} | tee "$work/table.md"
