"""Dev checks of the dataset formats and of structure-from-motion on real data.

Reads data only from the paths given on the command line (nothing is read otherwise)::

    # Blender loader vs the course npz: same cameras after OpenGL->OpenCV and 400->200 px?
    python benchmarks/formats_check.py --lego-blender PATH/lego_blender \\
        --lego-npz src/nerfkit/assets/lego_200x200.npz

    # SfM on phone photos: registration, timings; vs the tag poses of `nerfkit poses` if given
    # (they also choose the pairs of --matcher spatial)
    python benchmarks/formats_check.py --sfm-photos PATH/labubu/myscan_resized \\
        --tag-size 0.06 --tag-poses labubu_dataset/ --matcher sequential exhaustive spatial

Prints a JSON report (also written with --out). Timings depend on machine load.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def lego_check(blender_dir: str, npz_path: str) -> dict:
    """Max differences between the Blender loader (resampled to the npz size) and the npz."""
    from nerfkit.data.blender import load_blender
    from nerfkit.data.npz import load_npz

    ref = load_npz(npz_path)
    t0 = time.perf_counter()
    b = load_blender(blender_dir, size=max(ref.train.width, ref.train.height))
    seconds = time.perf_counter() - t0
    out = {
        "blender_load_seconds": round(seconds, 2),
        "size": [b.train.width, b.train.height],
        "near_far_blender": [b.near, b.far],
        "near_far_npz": [ref.near, ref.far],
    }
    for split in ("train", "val"):
        rv, bv = ref.splits[split], b.splits[split]
        if len(rv) == 0:
            continue
        # The course npz may keep a subset of a split: match each pose to the nearest Blender pose.
        d = np.abs(rv.c2w[:, None] - bv.c2w[None]).max(axis=(2, 3))
        j = d.argmin(1)
        out[split] = {
            "views_npz": len(rv),
            "views_blender": len(bv),
            "matched_blender_index": j.tolist()[:12],
            "max_abs_c2w_diff": float(d.min(1).max()),
            "max_abs_K_diff": float(np.abs(rv.K - bv.K[j]).max()),
            "image_mean_abs_diff_0_255": float(
                np.abs(rv.images.astype(np.int16) - bv.images[j].astype(np.int16)).mean()
            )
            if rv.images is not None and bv.images is not None
            else None,
        }
    return out


def read_tag_poses(path: str) -> dict[str, np.ndarray]:
    """name -> c2w from a poses.json of `nerfkit poses` (or a dataset folder/file load_scene reads)."""
    p = Path(path)
    pj = p / "poses.json" if p.is_dir() else p
    if pj.name == "poses.json" and pj.is_file():
        data = json.loads(pj.read_text())
        return {ph["file"]: np.asarray(ph["c2w"], np.float64) for ph in data["photos"] if ph.get("c2w")}
    from nerfkit.data.load import load_scene

    scene = load_scene(path)
    out = {}
    for v in scene.splits.values():
        for n, c in zip(v.names or [], v.c2w):
            out[Path(n).name] = c.astype(np.float64)
    return out


def sfm_check(photos: str, matcher: str, tag_size: float | None, tag_poses: str | None, max_image_size: int) -> dict:
    from nerfkit.sfm.colmap import colmap_name, run_sfm
    from nerfkit.sfm.frame import align_reconstruction, compare_poses, reconstruction_c2w

    tag = read_tag_poses(tag_poses) if tag_poses else {}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        result = run_sfm(
            photos,
            tmp,
            matcher=matcher,
            max_image_size=max_image_size,
            progress=True,
            guides={colmap_name(Path(n)): c for n, c in tag.items()},
        )
        frame = align_reconstruction(result, tag_size=tag_size, progress=True)
        total = time.perf_counter() - t0
        rep = result.report
        out = {
            "matcher": rep.matcher,
            "photos": rep.n_photos,
            "registered": len(rep.registered),
            "unregistered": rep.unregistered,
            "points": rep.n_points,
            "reprojection_error_px": round(rep.reprojection_error, 3),
            "models": rep.n_models,
            "seconds": rep.seconds,
            "seconds_total_with_alignment": round(total, 1),
            "camera": rep.camera,
            "frame": frame,
        }
        if tag:
            names, c2w = reconstruction_c2w(result.reconstruction)
            common = [i for i, n in enumerate(names) if n in tag]
            if len(common) >= 3:
                est = c2w[common]
                ref = np.stack([tag[names[i]] for i in common])
                sim = compare_poses(est, ref, with_scale=True)
                out["vs_tag_poses"] = {
                    "photos_in_both": len(common),
                    "tag_posed": len(tag),
                    "similarity_aligned": _round(sim),
                    "as_is_metric_frame": _round(compare_poses(est, ref, with_scale=False)) if tag_size else None,
                    "units": "degrees and metres (the tag frame)",
                }
    return out


def _round(d: dict) -> dict:
    return {k: (round(v, 5) if isinstance(v, float) else v) for k, v in d.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lego-blender", help="Blender-layout lego folder (transforms_*.json + PNGs)")
    ap.add_argument("--lego-npz", help="the course-layout lego npz to compare with")
    ap.add_argument("--sfm-photos", help="folder of photos to run SfM on")
    ap.add_argument(
        "--matcher", nargs="+", default=["auto"], help="matchers to try (auto, exhaustive, sequential, spatial)"
    )
    ap.add_argument("--max-image-size", type=int, default=1000)
    ap.add_argument("--tag-size", type=float, help="ArUco tag side in metres, to fix scale and up")
    ap.add_argument("--tag-poses", help="poses.json / dataset of `nerfkit poses` on the same photos, to compare with")
    ap.add_argument("--out", help="also write the JSON report here")
    args = ap.parse_args(argv)
    report: dict = {}
    if args.lego_blender and args.lego_npz:
        report["lego_blender_vs_npz"] = lego_check(args.lego_blender, args.lego_npz)
    if args.sfm_photos:
        report["sfm"] = [
            sfm_check(args.sfm_photos, m, args.tag_size, args.tag_poses, args.max_image_size) for m in args.matcher
        ]
    if not report:
        ap.print_help()
        return 2
    text = json.dumps(report, indent=2, default=str)
    print(text)
    if args.out:
        from nerfkit.io.atomic import write_text

        write_text(args.out, text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
