#!/usr/bin/env bash
# Whole-ERP sharpness against sharpness on horizon pinhole views, on the rendered 360° walk
# (issue 32, docs/360.md "Analysis on the sphere"). A measurement, not a test: it changes nothing.
#
#   scripts/erp-sharpness-compare.sh [--size 1024x512] [--fps 15] [--blur-samples 8] [--keep DIR]
#
# 1. Renders `keyframer-scene --preset walk --projection equirect` with motion blur (scene.json's
#    fast turn = the truly blurred frames; its hovers = the stop and the pauses around the turn).
# 2. Scores every frame with keyframer's own `select --every 1 --blur` (scores from the project's
#    cache) on: the whole ERP (`--projection pinhole`); the ERP's middle half of rows (|latitude|
#    < 45°, poles excluded), its top and its bottom quarter (exported with `--crop` as PNG; the
#    middle half is checked to equal what `select --projection equirect` scores); the ring of 4 views of 90° at
#    the ERP's equator resolution (`export --views ring:4 --view-fov 90`, PNG), per view, then the
#    mean and the min over the 4 views per frame. Both metrics: tenengrad and laplacian.
# 3. Prints per metric: Spearman rank correlation of every series with the views' mean (raw
#    scores, and the score / window mean the blur filter tests); the score in the turn against the
#    pauses around it (same place, only the rotation's blur differs) and at the stop against the
#    walking frames next to it; the frames the blur filter drops (ratio 0.8, window 10 = the
#    default, and 30 > the turn's length) with recall / precision against the turn's frames.
#    The filter rule is re-applied here to the combined series; it is checked against the
#    keyframes keyframer kept on every series it ran on (the script fails on a mismatch).
#    min10 / min30: the lowest score / window mean in the turn (the filter drops below 0.8).
#
# Needs target/release/keyframer and keyframer-scene (cargo build --release --workspace) and
# python3 (standard library only). About 4 minutes on 2 cores with llvmpipe.
set -euo pipefail
cd "$(dirname "$0")/.."
KF=target/release/keyframer
SCENE=target/release/keyframer-scene
size=1024x512
fps=15
blur_samples=8
keep=""
while [ $# -gt 0 ]; do
    case "$1" in
        --size) size=$2; shift 2 ;;
        --fps) fps=$2; shift 2 ;;
        --blur-samples) blur_samples=$2; shift 2 ;;
        --keep) keep=$2; shift 2 ;;
        *) echo "usage: $0 [--size WxH] [--fps N] [--blur-samples N] [--keep DIR]" >&2; exit 1 ;;
    esac
done
for b in "$KF" "$SCENE"; do
    [ -x "$b" ] || { echo "$b missing: cargo build --release --workspace" >&2; exit 1; }
done
if [ -n "$keep" ]; then
    mkdir -p "$keep"
    work=$(cd "$keep" && pwd)
else
    work=$(mktemp -d)
    trap 'rm -rf "$work"' EXIT
fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
W=${size%x*}
H=${size#*x}
# Views of 90° whose centre pixel spans the ERP's pixel angle (360° / W): W / π, even.
view=$(python3 -c "import math; print(2 * round($W / math.pi / 2))")
q=$((H / 4))

echo "render: walk ${size} @ ${fps} fps, --blur-samples ${blur_samples} -> $work/walk" >&2
"$SCENE" "$work/walk" --force -q --preset walk --projection equirect --size "$size" \
    --fps "$fps" --blur-samples "$blur_samples"
video="$work/walk/video.mp4"
"$KF" -q select "$video" --projection equirect --every 1 -o "$work/all.json" --force
echo "export: ring:4 views of 90° at ${view}x${view}, ERP bands of ${W}x${q} rows" >&2
"$KF" -q export "$work/all.json" --out "$work/ring" --views ring:4 --view-fov 90 \
    --view-size "$view" --format png --force 2>/dev/null
"$KF" -q export "$work/all.json" --out "$work/mid" --crop "0,$q,$W,$((2 * q))" --format png --force 2>/dev/null
"$KF" -q export "$work/all.json" --out "$work/top" --crop "0,0,$W,$q" --format png --force 2>/dev/null
"$KF" -q export "$work/all.json" --out "$work/bottom" --crop "0,$((H - q)),$W,$q" --format png --force 2>/dev/null

folders="ring/images/ring00 ring/images/ring01 ring/images/ring02 ring/images/ring03 mid/images top/images bottom/images"
for metric in tenengrad laplacian; do
    for window in 10 30; do
        echo "select --blur --blur-metric $metric --blur-window $window on the ERP and 7 folders" >&2
        # The whole ERP: its frames scored as ordinary (pinhole) ones.
        "$KF" -q select "$video" --projection pinhole --every 1 --blur --blur-metric "$metric" \
            --blur-window "$window" -o "$work/erp-$metric-$window.json" --force 2>/dev/null
        # What keyframer scores on a 360° input: the band |latitude| < 45° (= the mid crop).
        "$KF" -q select "$video" --projection equirect --every 1 --blur --blur-metric "$metric" \
            --blur-window "$window" -o "$work/band-$metric-$window.json" --force
        for f in $folders; do
            name=$(basename "$(dirname "$f")")
            case "$f" in ring/*) name=$(basename "$f") ;; esac
            "$KF" -q select "$work/$f" --every 1 --blur --blur-metric "$metric" \
                --blur-window "$window" -o "$work/$name-$metric-$window.json" --force 2>/dev/null
        done
    done
done

python3 - "$work" <<'PY'
import json
import sys

work = sys.argv[1]
scene = json.load(open(f"{work}/walk/scene.json"))
n = scene["frame_count"]
turns = scene["fast_turns"]
truth = {i for t in turns for i in range(t["start_frame"], t["end_frame"] + 1)}
RATIO = 0.8


def project(name, metric, window):
    return json.load(open(f"{work}/{name}-{metric}-{window}.json"))


def scores(name, metric):
    s = project(name, metric, 10)["cache"]["sharpness"]
    assert len(s) == 1 and s[0]["metric"].startswith(metric), (name, metric)
    return s[0]["scores"]


def window_mean(s, k, w):
    a, b = max(0, k - w), min(len(s) - 1, k + w)
    return sum(s[a : b + 1]) / (b + 1 - a)


def kept(s, w):
    # The blur filter's rule (src/steps/blur.rs), summed the same way.
    return [k for k in range(len(s)) if s[k] >= RATIO * window_mean(s, k, w)]


def ranks(v):
    order = sorted(range(len(v)), key=lambda i: v[i])
    r = [0.0] * len(v)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and v[order[j + 1]] == v[order[i]]:
            j += 1
        for k in range(i, j + 1):
            r[order[k]] = (i + j) / 2
        i = j + 1
    return r


def spearman(a, b):
    ra, rb = ranks(a), ranks(b)
    ma, mb = sum(ra) / len(ra), sum(rb) / len(rb)
    cov = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    va = sum((x - ma) ** 2 for x in ra)
    vb = sum((y - mb) ** 2 for y in rb)
    return cov / (va * vb) ** 0.5


def mean(s, frames):
    frames = list(frames)
    return sum(s[i] for i in frames) / len(frames)


# Same place, different blur: the turn against the pauses of the hover around it, and each
# other hover (a stop: no motion, no blur) against as many walking frames on either side.
turn_hover = [
    h for h in scene["hovers"] if any(h["start_frame"] <= i <= h["end_frame"] for i in truth)
]
pauses = [
    i for h in turn_hover for i in range(h["start_frame"], h["end_frame"] + 1) if i not in truth
]
stops = [h for h in scene["hovers"] if h not in turn_hover]


def stop_ratio(s):
    out = []
    for h in stops:
        a, b = h["start_frame"], h["end_frame"]
        m = b + 1 - a
        walk = [i for i in range(a - m, a) if i >= 0] + [i for i in range(b + 1, b + 1 + m) if i < n]
        out.append(mean(s, range(a, b + 1)) / mean(s, walk))
    return out


views = [f"ring0{i}" for i in range(4)]
bands = ["mid", "top", "bottom"]
print(f"# {work}: {n} frames; truly blurred (fast turn) {sorted(truth)[0]}-{sorted(truth)[-1]} "
      f"({len(truth)}), pauses around it {len(pauses)}, stops {[(h['start_frame'], h['end_frame']) for h in stops]}")
for metric in ["tenengrad", "laplacian"]:
    series = {"erp": scores("erp", metric)}
    for b in bands:
        series[f"erp-{b}"] = scores(b, metric)
    per_view = {v: scores(v, metric) for v in views}
    series["views-mean"] = [sum(x) / 4 for x in zip(*per_view.values())]
    series["views-min"] = [min(x) for x in zip(*per_view.values())]
    series.update(per_view)
    # keyframer's own 360° scores are those of the band (the mid crop, exported as PNG).
    band = scores("band", metric)
    assert all(abs(a - b) <= 1e-9 * max(abs(b), 1.0) for a, b in zip(band, series["erp-mid"])), \
        f"{metric}: select --projection equirect does not score the band"
    # Check the re-applied rule against what keyframer kept on the series it ran on.
    for name in ["erp", *bands, *views]:
        s = series["erp" if name == "erp" else (f"erp-{name}" if name in bands else name)]
        for w in (10, 30):
            got = project(name, metric, w)["keyframes"]
            assert got == kept(s, w), f"{name} {metric} window {w}: rule differs from keyframer"
    ref = series["views-mean"]
    local = lambda s: [s[k] / window_mean(s, k, 10) for k in range(len(s))]
    ref_local = local(ref)
    print(f"\n## {metric} (keyframer select --blur --blur-metric {metric}; filter ratio {RATIO})")
    print(
        f"{'series':<11} {'mean':>8} {'rho raw':>8} {'rho loc':>8} {'turn/pause':>10} {'stop/walk':>10}"
        f" {'w10 drop':>8} {'rec':>5} {'prec':>5} {'w30 drop':>8} {'rec':>5} {'prec':>5}"
        f" {'min10':>6} {'min30':>6}"
    )
    for name, s in series.items():
        row = f"{name:<11} {sum(s) / n:8.1f} {spearman(s, ref):8.3f} {spearman(local(s), ref_local):8.3f}"
        row += f" {mean(s, truth) / mean(s, pauses):10.3f}"
        row += " " + "/".join(f"{r:.3f}" for r in stop_ratio(s)).rjust(10)
        for w in (10, 30):
            dropped = set(range(n)) - set(kept(s, w))
            hit = len(dropped & truth)
            prec = f"{hit / len(dropped):.2f}" if dropped else "-"
            row += f" {len(dropped):8d} {hit / len(truth):5.2f} {prec:>5}"
        for w in (10, 30):
            row += f" {min(s[k] / window_mean(s, k, w) for k in truth):6.3f}"
        print(row)
    for w in (10, 30):
        for name in ["erp", "erp-mid", "views-mean", "views-min"]:
            dropped = sorted(set(range(n)) - set(kept(series[name], w)))
            print(f"dropped, window {w}, {name}: {dropped}")
print("\nrule check: the re-applied filter equals keyframer's keyframes on every series it ran on")
PY
