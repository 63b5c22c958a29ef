"""Real phone captures end to end, as a user runs them (no photos in the repository).

By default each capture goes through ``nerfkit capture`` (calibrate -> poses -> train for
``--minutes`` -> eval -> render the orbit and the object alone -> export the mesh) into
``--work/<capture>``, with ``--force`` so every step is timed afresh. The options the capture
command has no switch for (``--dist-model`` other than auto, ``--capture on|off``,
``--minutes 0``) run the same steps one by one, as does the SfM row of ``--sfm``.

Prints one row per capture: photos, photos with a tag detected, photos posed, the
distortion model chosen and its coefficients, the held-out reprojection error, fx against
the EXIF focal length; then the training steps, how well the training photos agree on the
table (``poses``' rough ceiling for held-out scores), the validation PSNR/SSIM as rendered and
with each held-out photo's pose fitted (the scene frozen) and each half's colour solved on
the other half (``nerfkit eval``), the same on the
object's own pixels, and the whole command's time. The contact sheet (validation photo
beside render) is RUN/eval_val.png, the videos are in RUN/videos::

    python benchmarks/capture_real.py --labubu PATH/labubu --steve PATH/steve --work OUT   # 3 minutes each
    python benchmarks/capture_real.py --steve PATH/steve --work OUT --minutes 0   # calibration, poses only
    python benchmarks/capture_real.py ... --sfm             # also: poses from SfM, tags ignored
    python benchmarks/capture_real.py ... --photos 30       # about 30 object photos per capture
    python benchmarks/capture_real.py ... --steps 1500      # a step budget (a loaded machine)

``nerfkit capture`` trains the NeRF and the splat (its default, ``--model both``); the splat's
steps, held-out scores and file size are printed under the table.

With ``--photos N`` only every k-th object photo (in name order, k = round(photos / N)) is
used, copied into the work folder: a capture of the size users bring (30-50 photos) made
from the dev captures (labubu 33 of 163, steve 28 of 56 for N = 30).

With ``--sfm`` each capture is also posed by structure-from-motion as if it had no tag
(``nerfkit poses --method colmap`` with the calibrated camera and no ``--tag-size``: the
table plane comes from the SfM points) and trained the same way, as a second row.

Each capture runs when its folder is given (``--labubu``, ``--steve``); outputs go to --work.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

# name -> (calibration subfolder, object subfolder, tag side in metres)
CAPTURES = {
    "labubu": ("calibration_resized", "myscan_resized", 0.06),
    "steve": ("calibration", "object", 0.055),
}


def run_figures(run: Path) -> dict:
    """The figures of a trained, evaluated run: steps and the validation scores."""
    e = json.loads((run / "eval_val.json").read_text())
    m = json.loads((run / "metrics.json").read_text())
    obj = e.get("object") or {}
    return {
        "steps": m["step"],
        "val_psnr": e["psnr"],
        "val_ssim": e["ssim"],
        "n_val": e["n_images"],
        "fitted_psnr": e.get("fitted", {}).get("psnr"),
        "fitted_ssim": e.get("fitted", {}).get("ssim"),
        "colour_psnr": e.get("colour_only", {}).get("psnr"),
        "object_psnr": obj.get("psnr"),
        "object_fitted": obj.get("psnr_fitted"),
        "sheet": str(run / "eval_val.png"),
        "run": str(run),
    }


def train_capture(name: str, out: Path, budget: list[str], capture: str, poses: str = "poses") -> dict:
    """Train, evaluate and render one capture's dataset step by step (``out/<poses>/dataset.npz``:
    the tag run's, or ``sfm`` for the SfM run's) for ``budget`` (``["--minutes", M]`` or
    ``["--steps", N]``); the figures of the run."""
    from nerfkit.cli import main

    run = out / f"run_{capture}" if poses == "poses" else out / f"run_{poses}_{capture}"
    if (run / "config.json").exists():  # an earlier run of this benchmark: train never replaces one
        shutil.rmtree(run)
    t0 = time.perf_counter()
    if (
        main(
            [
                "train",
                "--data",
                str(out / poses / "dataset.npz"),
                "--out",
                str(run),
                *budget,
                "--capture",
                capture,
            ]
        )
        != 0
    ):
        raise SystemExit(f"{name}: train failed")
    if main(["eval", str(run), "--split", "val"]) != 0:
        raise SystemExit(f"{name}: eval failed")
    if main(["render", str(run), "--force"]) != 0:
        raise SystemExit(f"{name}: render failed")
    return {**run_figures(run), "train_s": time.perf_counter() - t0}


def object_photos(name: str, folder: Path, work: Path, about: int) -> Path:
    """The capture's object folder, or (``about`` > 0) a copy of every k-th of its photos
    in name order, k = round(photos / about), in ``work/<name>/photos_every_<k>``."""
    src = folder / CAPTURES[name][1]
    if about <= 0:
        return src
    from nerfkit.images import list_images

    photos = list_images(src)
    every = max(1, round(len(photos) / about))
    dst = work / name / f"photos_every_{every}"
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for photo in photos[::every]:
        shutil.copy2(photo, dst / photo.name)
    return dst


def calibration_figures(name: str, cam: Path, poses: Path) -> dict:
    """What calibration and posing made of a capture: ``cam`` (camera.json) and the ``poses``
    folder (poses.json, and transforms.json when it built the dataset)."""
    c = json.loads(cam.read_text())
    photos = json.loads((poses / "poses.json").read_text())["photos"]
    detected = [x for x in photos if x.get("tags")]
    choice, views, agree = None, None, None
    if (poses / "transforms.json").exists():
        block = json.loads((poses / "transforms.json").read_text())["nerfkit"]
        choice, views = block.get("pose_choice"), sum(block["views"].values())
        agree = block.get("agreement")
    return {
        "capture": name,
        "calib_photos": len(c["images"]),
        "calib_used": c["photos_used"],
        "model": c["dist_model"],
        "dist": c["dist"],
        "heldout": c.get("heldout_rms"),
        "rms": c["rms"],
        "fx": c["fx"],
        "exif_fx": c["sanity"].get("exif_fx"),
        "photos": len(photos),
        "detected": len(detected),
        "posed": sum(x["used"] for x in photos),
        "second_pass": sum(1 for x in photos if x.get("detection")),
        "why": c["model_selection"]["why"],
        "dropped": [f"{x['file']}: {x['reason']}" for x in detected if not x["used"]],
        "pose_choice": choice["why"] if choice else "the tag's",
        "in_dataset": views,
        "tag_kept": len((choice or {}).get("tag_posed") or []),
        "agreement": agree,
    }


def splat_figures(out: Path) -> dict:
    """The splat's figures when the capture trained one (``out/splat_run``): steps, val PSNR/SSIM
    as rendered, the object's pixels, the size of splat.ply; {} otherwise."""
    run = out / "splat_run"
    if not (run / "eval_val.json").exists():
        return {}
    e = json.loads((run / "eval_val.json").read_text())
    m = json.loads((run / "metrics.json").read_text())
    return {
        "splat": {
            "steps": m["step"],
            "val_psnr": e["psnr"],
            "val_ssim": e["ssim"],
            "object_psnr": (e.get("object") or {}).get("psnr"),
            "ply_mb": (out / "splat.ply").stat().st_size / 1e6 if (out / "splat.ply").exists() else None,
            "sheet": str(run / "eval_val.png"),
        }
    }


def capture_command(name: str, folder: Path, objects: Path, work: Path, budget: list[str], method: str) -> dict:
    """One capture through ``nerfkit capture`` (its default models), as a user runs it; its
    figures and the whole command's time. ``budget``: ``["--minutes", M]`` or ``["--steps", N]``."""
    from nerfkit.cli import main

    calib, _, tag = CAPTURES[name]
    out = work / name
    t0 = time.perf_counter()
    if (
        main(
            [
                "capture",
                str(objects),
                "--calib",
                str(folder / calib),
                "--tag-size",
                str(tag),
                "--out",
                str(out),
                *budget,
                "--method",
                method,
                "--force",
            ]
        )
        != 0
    ):
        raise SystemExit(f"{name}: nerfkit capture failed")
    total = time.perf_counter() - t0
    return {
        **calibration_figures(name, out / "camera.json", out / "dataset"),
        **run_figures(out / "run"),
        **splat_figures(out),
        "total_s": total,
    }


def run_capture(
    name: str, folder: Path, objects: Path, work: Path, extra: list[str], dataset: bool = False, method: str = "auto"
) -> dict:
    """Calibrate and pose one capture step by step (``nerfkit calibrate``, ``nerfkit poses``)."""
    from nerfkit.cli import main

    calib, _, tag = CAPTURES[name]
    out = work / name
    cam = out / "camera.json"
    t0 = time.perf_counter()
    if main(["calibrate", str(folder / calib), "--tag-size", str(tag), "--out", str(cam), "--force", *extra]) != 0:
        raise SystemExit(f"{name}: calibrate failed")
    t_cal = time.perf_counter() - t0
    if (
        main(
            [
                "poses",
                str(objects),
                "--camera",
                str(cam),
                "--tag-size",
                str(tag),
                "--out",
                str(out / "poses"),
                "--method",
                method,
                "--force",
                *([] if dataset else ["--no-dataset"]),
            ]
        )
        != 0
    ):
        raise SystemExit(f"{name}: poses failed")
    return {**calibration_figures(name, cam, out / "poses"), "calib_s": t_cal}


def sfm_capture(name: str, objects: Path, work: Path) -> dict:
    """Pose the capture's object photos by SfM, ignoring the tags (the camera file of the
    tag run gives the intrinsics); the figures of the SfM report."""
    from nerfkit.cli import main

    out = work / name
    t0 = time.perf_counter()
    if (
        main(
            [
                "poses",
                str(objects),
                "--method",
                "colmap",
                "--camera",
                str(out / "camera.json"),
                "--out",
                str(out / "sfm"),
                "--force",
            ]
        )
        != 0
    ):
        raise SystemExit(f"{name}: poses --method colmap failed")
    rep = json.loads((out / "sfm" / "sfm_report.json").read_text())
    return {
        "capture": f"{name} (SfM, no tag)",
        "registered": rep["n_registered"],
        "photos": rep["n_photos"],
        "ground": rep.get("ground"),
        "sfm_s": time.perf_counter() - t0,
    }


def print_table(rows: list[dict]) -> None:
    from nerfkit.capture.report import table

    out = []
    sfm = [r for r in rows if "registered" in r]
    rows = [r for r in rows if "registered" not in r]
    for r in rows:
        k = r["dist"]
        exif = (
            f"{r['fx']:.1f} / {r['exif_fx']:.1f} ({(r['fx'] / r['exif_fx'] - 1) * 100:+.1f}%)"
            if r["exif_fx"]
            else f"{r['fx']:.1f} / no EXIF"
        )
        out.append(
            [
                r["capture"],
                f"{r['calib_used']}/{r['calib_photos']}",
                r["photos"],
                r["detected"],
                f"{r['posed']} ({r['posed'] / max(r['detected'], 1) * 100:.0f}%)",
                r["model"],
                " ".join(f"{v:+.3f}" for v in k[:2]) + (f" p {k[2]:+.3f} {k[3]:+.3f}" if any(k[2:4]) else ""),
                f"{r['heldout']:.3f}",
                exif,
                "-" if r["in_dataset"] is None else f"{r['in_dataset']} ({r['tag_kept']} tag-posed beside SfM's)",
            ]
        )
    print(
        table(
            out,
            [
                "capture",
                "calib used",
                "photos",
                "tag found",
                "posed",
                "model",
                "k1 k2 (p1 p2)",
                "held-out px",
                "fx / EXIF fx",
                "in the dataset",
            ],
            max_width=200,
        )
    )
    for r in rows:
        took = f"; calibration took {r['calib_s']:.1f} s" if "calib_s" in r else ""
        print(f"\n{r['capture']}: {r['why']}{took}; {r['second_pass']} photos found by the second detection pass")
        for d in r["dropped"]:
            print(f"  dropped {d}")
        print(f"  the dataset's poses: {r['pose_choice']}")
    for r in sfm:
        g = r["ground"]
        print(
            f"\n{r['capture']}: {r['registered']} of {r['photos']} photos registered in {r['sfm_s']:.0f} s; "
            + (
                "no table plane found"
                if g is None
                else f"table plane from {g['inliers']} of {g['candidates']} points, {g['tilt_deg']:.1f} deg from up"
            )
        )
    trained = [r for r in rows + sfm if "steps" in r]
    if trained:

        def pair(a, b):
            return "-" if a is None else f"{a:.2f}" + ("" if b is None else f" / {b:.2f}")

        def agreed(a):
            return "-" if a is None else f"{a['psnr']:.2f} ({a['psnr_exposure_evened']:.2f})"

        def took(r):
            if "total_s" in r:
                return f"{r['total_s'] / 60:.1f} min (capture)"
            return f"{r['train_s'] / 60:.1f} min (train on)"

        print()
        print(
            table(
                [
                    [
                        r["capture"],
                        r["capture_mode"],
                        r["steps"],
                        r["n_val"],
                        agreed(r.get("agreement")),
                        f"{r['val_psnr']:.2f}",
                        f"{r['val_ssim']:.3f}",
                        "-" if r["colour_psnr"] is None else f"{r['colour_psnr']:.2f}",
                        "-" if r["fitted_psnr"] is None else f"{r['fitted_psnr']:.2f} / {r['fitted_ssim']:.3f}",
                        pair(r["object_psnr"], r["object_fitted"]),
                        took(r),
                    ]
                    for r in trained
                ],
                [
                    "capture",
                    "--capture",
                    "steps",
                    "val views",
                    "photos agree on the table (exposure evened)",
                    "val PSNR",
                    "val SSIM",
                    "PSNR, colour (other half)",
                    "PSNR / SSIM, pose + colour (other half)",
                    "object's pixels (fitted)",
                    "time",
                ],
                max_width=200,
            )
        )
        for r in trained:
            print(f"{r['capture']}: contact sheet {r['sheet']}, videos {Path(r['run']) / 'videos'}")
        for r in trained:
            if "splat" in r:
                g = r["splat"]
                obj = "-" if g["object_psnr"] is None else f"{g['object_psnr']:.2f}"
                size = "" if g["ply_mb"] is None else f", splat.ply {g['ply_mb']:.1f} MB"
                print(
                    f"{r['capture']} splat: {g['steps']} steps, val {g['val_psnr']:.2f} / {g['val_ssim']:.3f} "
                    f"as rendered, the object's pixels {obj}{size}; "
                    f"contact sheet {g['sheet']}"
                )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name in CAPTURES:
        ap.add_argument(f"--{name}", type=Path, help=f"the {name} capture folder (not given: {name} is skipped)")
    ap.add_argument("--work", type=Path, required=True, help="folder for the datasets, runs and renders")
    ap.add_argument("--only", choices=list(CAPTURES), help="run one capture")
    ap.add_argument("--dist-model", default="auto", help="passed to nerfkit calibrate (compare with e.g. k1k2p1p2)")
    ap.add_argument("--minutes", type=float, default=3.0, help="training minutes per capture (0: no training)")
    ap.add_argument("--steps", type=int, help="train this many steps instead of --minutes (a loaded machine)")
    ap.add_argument("--capture", default="auto", choices=["auto", "on", "off"], help="passed to nerfkit train")
    ap.add_argument(
        "--sfm", action="store_true", help="also pose each capture by SfM without its tags, and train on that"
    )
    ap.add_argument(
        "--method",
        default="auto",
        choices=["auto", "tags"],
        help="nerfkit poses --method for the tag run (auto: SfM poses in the tag's frame when they hold up)",
    )
    ap.add_argument(
        "--photos",
        type=int,
        default=0,
        metavar="N",
        help="use about N of each capture's object photos, evenly spaced (default 0: all)",
    )
    args = ap.parse_args()
    rows = []
    for name in CAPTURES:
        folder = getattr(args, name)
        if args.only and name != args.only:
            continue
        if folder is None:
            continue
        if not folder.is_dir():
            print(f"skipping {name}: no folder {folder}", file=sys.stderr)
            continue
        objects = object_photos(name, folder, args.work, args.photos)
        budget = ["--steps", str(args.steps)] if args.steps else ["--minutes", str(args.minutes)]
        if args.minutes > 0 and args.dist_model == "auto" and args.capture == "auto":
            row = capture_command(name, folder, objects, args.work, budget, args.method)
        else:  # what `nerfkit capture` has no switch for: the steps one by one
            row = run_capture(
                name,
                folder,
                objects,
                args.work,
                ["--dist-model", args.dist_model],
                dataset=args.minutes > 0,
                method=args.method,
            )
            if args.minutes > 0:
                row.update(train_capture(name, args.work / name, budget, args.capture))
        rows.append({**row, "capture_mode": args.capture})
        if args.sfm:
            srow = sfm_capture(name, objects, args.work)
            if args.minutes > 0:
                srow.update(
                    capture_mode=args.capture,
                    **train_capture(name, args.work / name, budget, args.capture, poses="sfm"),
                )
            rows.append(srow)
    print()
    print_table(rows)
    return 0 if rows else 1


if __name__ == "__main__":
    sys.exit(main())
