"""How fine a capture's table texture is against what one pixel of its photos sees.

The ``fast`` model paints a capture's table as a texture of ``--table-resolution`` texels a
side (``nerfkit.surroundings.table.TablePlane``): half of them span the disc of the scene's
radius about the object's foot, so a texel there is ``4 radius / resolution`` on a side. A
pixel of a training photo sees a patch of the table whose side depends on the distance and
the angle (``nerfkit.surroundings.table.plane_footprint``). This prints, per posed capture dataset,
the median side of that patch over the training photos' pixels that meet the table within
the radius, the texel's side at each resolution, and their ratio: above 1, a texel is coarser
than a pixel, and the table's finest grain is out of the texture's reach.

    python benchmarks/table_footprint.py --capture NAME=DATASET [...] [--resolutions 512,1024]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import heldout  # noqa: E402

from nerfkit.errors import NerfkitError  # noqa: E402
from nerfkit.scene_extent import sphere_radius  # noqa: E402
from nerfkit.surroundings.table import plane_footprint, texel_side


def footprint_row(name: str, scene, resolutions: list[int]) -> dict:
    """One capture's figures: its training photos, radius (m), the median pixel footprint on the
    table (mm) and, per resolution, the texel's side (mm) and texel / footprint."""
    radius = sphere_radius(scene)
    foot = None if scene.table is None else plane_footprint(scene.train, scene.table, scene.center, radius)
    row: dict = {"capture": name, "photos": len(scene.train), "radius_m": radius, "footprint_mm": None}
    if foot is not None:
        row["footprint_mm"] = 1000.0 * foot
    for res in resolutions:
        texel = texel_side(radius, res)
        row[f"texel_{res}_mm"] = 1000.0 * texel
        row[f"ratio_{res}"] = None if foot is None else texel / foot
    return row


def table_markdown(rows: list[dict], resolutions: list[int]) -> str:
    head = "| capture | training photos | radius (m) | pixel footprint (mm) |"
    head += "".join(f" texel at {r} (mm) | texel / footprint at {r} |" for r in resolutions)
    lines = [head, "|---|---:|---:|---:|" + "---:|---:|" * len(resolutions)]

    def num(v) -> str:
        return "-" if v is None else f"{v:.2f}"

    for r in rows:
        cells = [r["capture"], str(r["photos"]), f"{r['radius_m']:.3f}", num(r["footprint_mm"])]
        for res in resolutions:
            cells += [num(r[f"texel_{res}_mm"]), num(r[f"ratio_{res}"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--capture", action="append", default=[], metavar="NAME=DATASET", help="a posed capture dataset")
    ap.add_argument("--resolutions", default="512,1024", help="texture sizes (texels a side), comma-separated")
    args = ap.parse_args()
    from nerfkit.data.load import load_scene

    resolutions = [int(r) for r in args.resolutions.split(",") if r.strip()]
    if not args.capture:
        ap.error("give at least one --capture NAME=DATASET")
    try:
        captures = heldout.parse_captures(args.capture)
        rows = [footprint_row(name, load_scene(path), resolutions) for name, path in captures.items()]
    except NerfkitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(table_markdown(rows, resolutions))
    return 0


if __name__ == "__main__":
    sys.exit(main())
