"""Benchmark of tag detection and calibration on synthetic 12-megapixel phone photos.

Renders N photos (4032x3024, iPhone-like fx ~ 3030 px, mild distortion, JPEG with EXIF
FocalLengthIn35mmFilm) of a sheet of 6 tags, then times what ``nerfkit calibrate`` does:
decoding the JPEGs upright, detecting tags on a downscaled copy with full-resolution corner
refinement (``--jobs`` threads), and calibrating with an estimated sheet layout; also a
re-run that hits the detection cache. Prints timings and the calibration error against
the true camera::

    python benchmarks/capture.py                 # 50 photos, kept in --work for the next run
    python benchmarks/capture.py --n 20 --jobs 1,2

Photos are rendered at half size and upscaled (rendering 12 MP directly takes minutes);
they are kept in --work and reused. Timings depend on machine load: run it on an idle
machine for figures you want to quote.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def make_photos(folder: Path, n: int, seed: int) -> tuple:
    import cv2
    import numpy as np

    from nerfkit.capture import synthetic as S

    W, H = 4032, 3024
    fx_full = 26.0 * np.hypot(W, H) / 43.2666
    K_half = np.array([[fx_full / 2, 0, (W / 2 - 1) / 2 + 3.0], [0, fx_full / 2, (H / 2 - 1) / 2 - 2.0], [0, 0, 1]])
    K_full = K_half.copy()
    K_full[:2] *= 2.0
    K_full[:2, 2] += 0.5  # OpenCV pixel centres: (c + 0.5) * 2 - 0.5
    dist = np.array([0.03, -0.05, 0.0, 0.0, 0.0])
    done = folder / "done.txt"
    if done.exists() and done.read_text() == f"{n} {seed}":
        return K_full, dist
    folder.mkdir(parents=True, exist_ok=True)
    for f in folder.glob("*.jpg"):
        f.unlink()
    decal, layout = S.tag_sheet([0, 1, 2, 3, 4, 5], 0.06, 2, 0.03, texels_per_module=40)
    scene = S.SynthScene([decal], table=S.table_texture(seed))
    rng = np.random.default_rng(seed)
    extent = 0.5 * max(decal.texture.shape[:2]) * decal.res
    poses = S.sheet_views(n, K_half, (W // 2, H // 2), extent, rng)
    rays = S.camera_rays(K_half, dist, W // 2, H // 2, supersample=1)
    t0 = time.perf_counter()
    for i, p in enumerate(poses):
        half = S.render(scene, rays, p, supersample=1, noise=1.5, rng=rng)
        full = cv2.resize(half, (W, H), interpolation=cv2.INTER_CUBIC)
        S.write_photo(folder / f"IMG_{i:04d}.jpg", full, quality=92, f35=26)
        print(f"\rrendered {i + 1}/{n} photos ({time.perf_counter() - t0:.0f} s)", end="", file=sys.stderr)
    print(file=sys.stderr)
    done.write_text(f"{n} {seed}")
    return K_full, dist


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=50, help="photos (default: 50)")
    parser.add_argument("--jobs", default="1,2", help="thread counts to time, comma-separated (default: 1,2)")
    parser.add_argument("--detect-size", type=int, default=2000, help="detection copy long side (default: 2000)")
    parser.add_argument("--work", required=True, help="where the rendered photos are kept")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    import numpy as np

    from nerfkit.capture import calibrate as C
    from nerfkit.capture.photos import group_by_size, scan_photos
    from nerfkit.images import load_image_uint8

    folder = Path(args.work) / f"sheet_{args.n}_{args.seed}"
    K_true, dist_true = make_photos(folder, args.n, args.seed)
    files = sorted(folder.glob("*.jpg"))

    t0 = time.perf_counter()
    for f in files[:5]:
        load_image_uint8(f)
    decode = (time.perf_counter() - t0) / 5

    rows = []
    records = None
    for jobs in [int(j) for j in args.jobs.split(",")]:
        t0 = time.perf_counter()
        records = scan_photos(
            folder, "DICT_4X4_50", detect_side=args.detect_size, cache_path=None, jobs=jobs, progress=False
        )
        rows.append((f"decode + detect, {jobs} thread(s)", time.perf_counter() - t0))
    cache = Path(args.work) / "cache.json"
    cache.unlink(missing_ok=True)
    scan_photos(folder, "DICT_4X4_50", detect_side=args.detect_size, cache_path=cache, jobs=2, progress=False)
    t0 = time.perf_counter()
    records = scan_photos(folder, "DICT_4X4_50", detect_side=args.detect_size, cache_path=cache, jobs=2, progress=False)
    rows.append(("re-run with the detection cache", time.perf_counter() - t0))
    size, kept = group_by_size(records)
    t0 = time.perf_counter()
    cal = C.calibrate_records(kept, size, 0.06, None, C.CalibrateConfig())
    rows.append(("calibration (estimated layout)", time.perf_counter() - t0))

    n_tags = sum(len(r.detection.ids) for r in records)
    print(
        f"{len(files)} photos of {size[0]}x{size[1]}, {n_tags} tags detected; JPEG decode + EXIF rotate "
        f"{decode:.2f} s/photo"
    )
    for name, sec in rows:
        print(f"  {name:<36} {sec:7.2f} s  ({sec / len(files):.3f} s/photo)")
    K = cal.K
    rel = [K[0, 0] / K_true[0, 0] - 1, K[1, 1] / K_true[1, 1] - 1, K[0, 2] - K_true[0, 2], K[1, 2] - K_true[1, 2]]
    print(
        f"calibration: rms {cal.rms:.3f} px, {sum(r.used for r in kept)} photos used; fx {rel[0] * 100:+.3f}%, "
        f"fy {rel[1] * 100:+.3f}%, cx {rel[2]:+.2f} px, cy {rel[3]:+.2f} px off the truth; "
        f"k1 {cal.dist[0]:+.4f} (true {dist_true[0]:+.4f})"
    )
    print(f"sanity warnings: {cal.sanity['warnings'] or 'none'}; fx / EXIF fx {cal.sanity.get('fx_over_exif_fx')}")
    return 0 if np.isfinite(cal.rms) else 1


if __name__ == "__main__":
    sys.exit(main())
