"""One matching run of scripts/bench/bench_match.py in its own process (so that its peak memory is
its own): striptri's ``run_match``, or COLMAP's pipeline through pycolmap. Prints one JSON line.

    python scripts/bench/match_worker.py striptri PROJECT IMAGES OUT SCALE FEATURES
    python scripts/bench/match_worker.py colmap PROJECT IMAGES OUT SCALE FEATURES
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def striptri_run(project, images, out, scale, features) -> dict:
    from striptri.match.pipeline import MatchOptions, run_match

    p = run_match(project, images, out, MatchOptions(scale=scale, max_features=features))
    return {"seconds": dict(p.seconds), "photos": len(p.features), "pairs": p.pairs, "verified": p.verified_pairs,
            "matches": p.matches, "tie_points": p.kept_tracks, "rays": p.rays,
            "features": float(sorted(p.features)[len(p.features) // 2]), "peak_mb": dict(p.peak_mb)}


def colmap_run(project, images, out, scale, features) -> dict:
    """COLMAP's own pipeline on the same images and candidate pairs: SIFT features at the same
    resolution (max_image_size) and number, matching and geometric verification of striptri's
    candidate pairs (match_image_pairs), then COLMAP's incremental mapping (its own orientations and
    points; the intrinsics held). Triangulating with the approximate orientations held
    (triangulate_points) is not a fair stand-in: with approximations off by a degree COLMAP's
    reprojection limit (4 px) rejects most rays (504 points of 50,490 matches on 8 photos). GLOMAP's
    global mapping (pycolmap.global_mapping) is no faster here: 499 s on the 100-photo block's
    database against the incremental mapping's 476 s. Before the mapping a JSON line with the
    stages done so far is printed (the run may be stopped there: bench_match.py --limit)."""
    import pycolmap

    from striptri.io.project_reader import read_project
    from striptri.match.frames import digital_frames
    from striptri.match.pipeline import _image_paths, _pairs, _terrain_height, MatchOptions

    seconds = {}
    t = time.perf_counter()
    project_dir, out = Path(project), Path(out)
    out.mkdir(parents=True)
    proj = read_project(project_dir, plate_measurements_optional=True)
    paths = _image_paths(proj, Path(images), project_dir)
    names = [p.name for p in paths]
    cams = proj.cameras
    W, H = (int(v) for v in cams.size_px[0])
    s = float(cams.pixel_size[0])
    c, xp, yp = cams.interior[0, :3]
    db = out / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = f"{c / s},{c / s},{W / 2 + xp / s},{H / 2 - yp / s}"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = int(round(max(W, H) * scale))
    extraction.mergedict({"sift": {"max_num_features": int(features)}})
    extraction.num_threads = -1
    seconds["setup"] = time.perf_counter() - t
    t = time.perf_counter()
    pycolmap.extract_features(db, images, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    seconds["features"] = time.perf_counter() - t
    t = time.perf_counter()
    pairs = _pairs(proj, _terrain_height(proj, MatchOptions()), digital_frames(proj).half)
    pair_file = out / "pairs.txt"
    pair_file.write_text("".join(f"{names[a]} {names[b]}\n" for a, b in pairs))
    print(json.dumps({"seconds": dict(seconds), "photos": len(names), "pairs": len(pairs), "verified": 0, "matches": 0,
                      "tie_points": 0, "rays": 0, "registered": 0, "models": 0, "features": float("nan"),
                      "stopped": "pair matching"}), flush=True)  # should the matching be stopped (--limit)
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(pair_file)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = -1
    pycolmap.match_image_pairs(db, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    seconds["pair matching"] = time.perf_counter() - t
    database = pycolmap.Database.open(str(db))
    verified = int(database.num_verified_image_pairs())
    matches = int(database.num_inlier_matches())
    database.close()
    partial = {"seconds": dict(seconds), "photos": len(names), "pairs": len(pairs), "verified": verified,
               "matches": matches, "tie_points": 0, "rays": 0, "registered": 0, "models": 0,
               "features": float("nan"), "stopped": "incremental mapping"}
    print(json.dumps(partial), flush=True)  # what was done, should the mapping be stopped (--limit)
    t = time.perf_counter()
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = -1
    mapping.ba_refine_focal_length = mapping.ba_refine_principal_point = mapping.ba_refine_extra_params = False
    mapping.extract_colors = False
    mapping.random_seed = 0
    (out / "sparse").mkdir()
    models = pycolmap.incremental_mapping(db, images, out / "sparse", mapping)
    seconds["incremental mapping"] = time.perf_counter() - t
    best = max(models.values(), key=lambda m: m.num_reg_images(), default=None)
    rays = int(sum(p.track.length() for p in best.points3D.values())) if best else 0
    return {"seconds": seconds, "photos": len(names), "pairs": len(pairs), "verified": verified,
            "matches": matches, "tie_points": int(best.num_points3D()) if best else 0, "rays": rays,
            "registered": int(best.num_reg_images()) if best else 0, "models": len(models), "features": float("nan")}


def main() -> None:
    which, project, images, out, scale, features = sys.argv[1:7]
    run = striptri_run if which == "striptri" else colmap_run
    t = time.perf_counter()
    result = run(project, images, out, float(scale), int(features))
    result["whole_s"] = time.perf_counter() - t
    print(json.dumps(result))


if __name__ == "__main__":
    main()
