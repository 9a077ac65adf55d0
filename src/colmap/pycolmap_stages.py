"""keyframer's driver of pycolmap's sparse stages (`keyframer colmap --engine pycolmap`).

keyframer writes this file into the workspace and runs its stages through one process:
  python pycolmap_stages.py serve
reads one stage a line on stdin, as JSON {"log": LOG, "argv": [STAGE, ARG, ...]}, runs it with
its stdout and stderr appended to LOG, and answers on stdout with one JSON line {"code": EXIT
CODE, "cpu_s": CPU SECONDS} (the process's user + system time since the previous answer, the
first answer's including the interpreter's start and pycolmap's import); it ends at the end of
stdin. pycolmap is imported once for all of a round's stages, not once per stage (~0.2 CPU-s
each). Each stage also runs alone, as a process of its own:
  python pycolmap_stages.py version
  python pycolmap_stages.py feature_extractor --database_path DB --image_path DIR
      --camera_mode single|per_folder --camera_model M [--camera_params P] [--mask_path DIR]
      [--max_num_features N] [--image_list TXT --existing_camera_id ID]
  python pycolmap_stages.py rig_configurator --database_path DB --rig_config_path JSON
  python pycolmap_stages.py matches_importer --database_path DB --match_list_path TXT
      [--match_type pairs]
  python pycolmap_stages.py sequential_matcher --database_path DB --overlap N
  python pycolmap_stages.py exhaustive_matcher --database_path DB
  python pycolmap_stages.py mapper --database_path DB --image_path DIR --output_path DIR
      [--fixed_intrinsics 0|1] [--fixed_rig 0|1] [--option KEY=VALUE ...] [--input_path DIR]
      [--random_seed N]
  python pycolmap_stages.py global_mapper --database_path DB --image_path DIR --output_path DIR
      [--fixed_intrinsics 0|1] [--random_seed N]
Each stage prints what it does to stdout (keyframer keeps it in logs/<stage>.log) and exits
non-zero with a message on stderr when it fails. The mappers write model i into OUTPUT/i (none
when they keep no model: that is a result, not a failure). COLMAP's random draws are seeded
(SEED: the global generator, two-view verification's RANSAC, the mappers; a mapper's
--random_seed replaces it for its own draws), so that a stage run again on the same input starts
from the same draws.
"""

import argparse
import json
import os
import resource
import sys
import time
import traceback

import pycolmap


# The seed of COLMAP's random draws (RANSAC, the mappers), so that a stage run again on the same
# input starts from the same draws.
SEED = 0


def log(msg):
    print(msg, flush=True)


IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


def image_names(root):
    """The images under `root` as COLMAP names them (relative, '/'-separated), sorted."""
    names = []
    for dirpath, _, files in os.walk(root):
        for f in files:
            if f.lower().endswith(IMAGE_SUFFIXES) and not f.startswith("."):
                rel = os.path.relpath(os.path.join(dirpath, f), root)
                names.append(rel.replace(os.sep, "/"))
    return sorted(names)


def feature_extractor(a):
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.use_gpu = False
    if a.max_num_features:
        extraction.sift.max_num_features = a.max_num_features
    mode = {"single": pycolmap.CameraMode.SINGLE, "per_folder": pycolmap.CameraMode.PER_FOLDER}
    names = image_names(a.image_path)
    if a.image_list:
        # Only the listed images (a later round's new ones), sharing an existing camera.
        with open(a.image_list) as f:
            listed = {line.strip() for line in f if line.strip()}
        missing = sorted(listed - set(names))
        if missing:
            raise SystemExit(f"{a.image_list}: {missing[0]} is not an image under {a.image_path}")
        names = [n for n in names if n in listed]
    # This COLMAP skips an image whose mask is missing (3.8 used the whole image), and a rig
    # export masks only the views that see the nadir cap: images with and without a mask are
    # extracted in two passes, the second without a mask folder.
    masked = [n for n in names if a.mask_path and os.path.isfile(os.path.join(a.mask_path, n + ".png"))]
    unmasked = [n for n in names if n not in set(masked)]
    for group, mask_path in ((masked, a.mask_path), (unmasked, None)):
        if not group:
            continue
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = a.camera_model
        if a.existing_camera_id is not None:
            reader.existing_camera_id = a.existing_camera_id
        if a.camera_params:
            reader.camera_params = a.camera_params
        if mask_path:
            reader.mask_path = mask_path
        log(f"{len(group)} images {'with' if mask_path else 'without'} a mask")
        pycolmap.extract_features(
            a.database_path,
            a.image_path,
            image_names=group,
            camera_mode=mode[a.camera_mode],
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
    db = pycolmap.Database.open(a.database_path)
    log(f"{db.num_images()} images, {db.num_cameras()} cameras, {db.num_keypoints()} keypoints")
    db.close()


def rig_configurator(a):
    configs = pycolmap.read_rig_config(a.rig_config_path)
    db = pycolmap.Database.open(a.database_path)
    pycolmap.apply_rig_config(configs, db)
    log(f"{db.num_rigs()} rigs, {db.num_frames()} frames, {db.num_images()} images")
    db.close()


def matcher(a):
    matching = pycolmap.FeatureMatchingOptions()
    matching.use_gpu = False
    device = pycolmap.Device.cpu
    # Two-view verification's RANSAC draws from its own seeded generator (else each worker
    # thread seeds itself at random and a pair's inliers vary from run to run).
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = SEED
    if a.stage == "matches_importer":
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = a.match_list_path
        pycolmap.match_image_pairs(a.database_path, matching, pairing, verification, device=device)
    elif a.stage == "sequential_matcher":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = a.overlap
        pycolmap.match_sequential(a.database_path, matching, pairing, verification, device=device)
    else:
        pairing = pycolmap.ExhaustivePairingOptions()
        pycolmap.match_exhaustive(a.database_path, matching, pairing, verification, device=device)
    db = pycolmap.Database.open(a.database_path)
    log(f"{db.num_matches()} matches, {db.num_verified_image_pairs()} verified image pairs")
    db.close()


def set_option(options, key, value):
    """Sets KEY (as `colmap mapper --Mapper.KEY` names it) on the pipeline options or on their
    `mapper` / `triangulation` parts, converting VALUE to the option's type."""
    for target in (options, options.mapper, options.triangulation):
        if hasattr(target, key):
            current = getattr(target, key)
            if isinstance(current, bool):
                v = value.strip().lower()
                if v not in ("0", "1", "true", "false"):
                    raise SystemExit(f"mapper option {key}={value}: not a boolean (0/1/true/false)")
                setattr(target, key, v in ("1", "true"))
            elif isinstance(current, int):
                setattr(target, key, int(value))
            elif isinstance(current, float):
                setattr(target, key, float(value))
            else:
                setattr(target, key, value)
            return
    raise SystemExit(f"mapper option {key}: pycolmap {pycolmap.__version__} has no such option")


def mapper(a):
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = a.random_seed
    if a.fixed_intrinsics:
        options.ba_refine_focal_length = False
        options.ba_refine_principal_point = False
        options.ba_refine_extra_params = False
    if a.fixed_rig:
        # The rig's relative poses are known exactly (the views of one 360° frame).
        options.ba_refine_sensor_from_rig = False
    for o in a.option or []:
        key, _, value = o.partition("=")
        set_option(options, key.strip().removeprefix("Mapper."), value.strip())
    models = pycolmap.incremental_mapping(
        a.database_path, a.image_path, a.output_path, options, input_path=a.input_path or ""
    )
    report(models)


def global_mapper(a):
    options = pycolmap.GlobalPipelineOptions()
    options.random_seed = a.random_seed
    if a.fixed_intrinsics:
        ba = options.mapper.bundle_adjustment
        ba.refine_focal_length = False
        ba.refine_principal_point = False
        ba.refine_extra_params = False
    models = pycolmap.global_mapping(a.database_path, a.image_path, a.output_path, options)
    report(models)


def report(models):
    for i, r in sorted(models.items()):
        log(f"model {i}: {r.num_reg_images()} images, {r.num_points3D()} points")
    if not models:
        log("no model")


def parser():
    p = argparse.ArgumentParser(prog="pycolmap_stages.py")
    sub = p.add_subparsers(dest="stage", required=True)
    sub.add_parser("version")
    sub.add_parser("serve")
    fe = sub.add_parser("feature_extractor")
    fe.add_argument("--database_path", required=True)
    fe.add_argument("--image_path", required=True)
    fe.add_argument("--camera_mode", choices=["single", "per_folder"], required=True)
    fe.add_argument("--camera_model", required=True)
    fe.add_argument("--camera_params")
    fe.add_argument("--mask_path")
    fe.add_argument("--max_num_features", type=int)
    fe.add_argument("--image_list")
    fe.add_argument("--existing_camera_id", type=int)
    rc = sub.add_parser("rig_configurator")
    rc.add_argument("--database_path", required=True)
    rc.add_argument("--rig_config_path", required=True)
    mi = sub.add_parser("matches_importer")
    mi.add_argument("--database_path", required=True)
    mi.add_argument("--match_list_path", required=True)
    mi.add_argument("--match_type", choices=["pairs"], default="pairs")
    sm = sub.add_parser("sequential_matcher")
    sm.add_argument("--database_path", required=True)
    # The colmap command's name of it too, as keyframer passes it to both.
    sm.add_argument("--overlap", "--SequentialMatching.overlap", dest="overlap", type=int, required=True)
    em = sub.add_parser("exhaustive_matcher")
    em.add_argument("--database_path", required=True)
    mp = sub.add_parser("mapper")
    mp.add_argument("--database_path", required=True)
    mp.add_argument("--image_path", required=True)
    mp.add_argument("--output_path", required=True)
    mp.add_argument("--fixed_intrinsics", type=int, choices=[0, 1], default=0)
    mp.add_argument("--fixed_rig", type=int, choices=[0, 1], default=0)
    mp.add_argument("--option", action="append")
    mp.add_argument("--input_path")
    mp.add_argument("--random_seed", type=int, default=SEED)
    gm = sub.add_parser("global_mapper")
    gm.add_argument("--database_path", required=True)
    gm.add_argument("--image_path", required=True)
    gm.add_argument("--output_path", required=True)
    gm.add_argument("--fixed_intrinsics", type=int, choices=[0, 1], default=0)
    gm.add_argument("--random_seed", type=int, default=SEED)
    return p


def run(a):
    log(f"pycolmap {pycolmap.__version__}: {a.stage}")
    pycolmap.set_random_seed(SEED)
    start = time.monotonic()
    {
        "feature_extractor": feature_extractor,
        "rig_configurator": rig_configurator,
        "matches_importer": matcher,
        "sequential_matcher": matcher,
        "exhaustive_matcher": matcher,
        "mapper": mapper,
        "global_mapper": global_mapper,
    }[a.stage](a)
    log(f"{a.stage}: {time.monotonic() - start:.1f} s")


def cpu_s():
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def exit_code(e):
    """The exit status a process ending with SystemExit `e` has (its message to stderr)."""
    if e.code is None:
        return 0
    if isinstance(e.code, int):
        return e.code
    print(e.code, file=sys.stderr, flush=True)
    return 1


def serve():
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    before = 0.0
    for line in sys.stdin:
        if not line.strip():
            continue
        request = json.loads(line)
        sys.stdout.flush()
        sys.stderr.flush()
        fd = os.open(request["log"], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
        code = 0
        try:
            a = parser().parse_args(request["argv"])
            if a.stage in ("version", "serve"):
                raise SystemExit(f"{a.stage}: not a stage")
            run(a)
        except SystemExit as e:
            code = exit_code(e)
        except Exception:
            traceback.print_exc()
            code = 1
        sys.stdout.flush()
        sys.stderr.flush()
        now = cpu_s()
        answers.write(json.dumps({"code": code, "cpu_s": now - before}) + "\n")
        before = now


def main():
    a = parser().parse_args()
    if a.stage == "version":
        print(pycolmap.__version__)
        return
    if a.stage == "serve":
        serve()
        return
    run(a)


if __name__ == "__main__":
    sys.exit(main())
