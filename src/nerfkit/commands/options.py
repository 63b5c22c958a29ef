"""The options of the commands on a trained run, one dataclass per command: each field is one
flag (:func:`~nerfkit.config.option`: its default, help and range), so the command's parser
(:func:`~nerfkit.config.add_dataclass_args`), its Python function in :mod:`nerfkit.api` (whose
keyword defaults are these fields') and its checks (:func:`~nerfkit.config.check_ranges`) all
read them from here. Plain Python (no NumPy): the command modules, which ``nerfkit --help``
imports, import :mod:`~nerfkit.commands.pipeline`, which imports this.

A field's ``needs`` metadata names the output it acts on (``export``: "--mesh", ...); given
without that output, the command says the option does nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..config import option
from ..table_cut import TABLE_CUT


@dataclass(frozen=True)
class ExportOptions:
    """The options of ``nerfkit export`` (:func:`nerfkit.api.export`) beside its outputs and run."""

    background_dome: bool = option(
        True,
        "(splat runs with a learned background, as captures) leave out the dome of Gaussians "
        "that carries the background into the file",
        negated=True,
        needs="--splat",
    )
    resolution: int = option(
        256, "grid cells per side", min=8, max=1024, group="mesh", needs="--mesh", metavar="RESOLUTION"
    )
    threshold: float | None = option(
        None,
        "density of the surface",
        default_help="the density at which 1/256 of the meshed cube's width is 7% opaque, whatever the "
        "scene's units: lego's about 6, a 15-cm object's in metres about 120; printed; higher = tighter, "
        "fewer floaters",
        above=0,
        group="mesh",
        needs="--mesh",
        metavar="THRESHOLD",
    )
    box_scale: float = option(
        1.0,
        "scale the cube meshed, and the scene box points are cropped to",
        above=0,
        max=100,
        group="mesh",
        needs="--mesh or --points",
        metavar="BOX_SCALE",
    )
    table_cut: float = option(
        TABLE_CUT,
        "(captures) clear density within this fraction of the object's height above the table, where "
        "nothing rises out of that slab, and pieces apart from the object lower than three times that: "
        "the tags and sheet painted into density (0: clear only under the table)",
        min=0,
        max=1,
        group="mesh",
        needs="--mesh",
        metavar="TABLE_CUT",
    )
    # a mesh's vertices are coloured from this many of the training views, evenly spread
    # (nerfkit.export: how large they are rendered, and when a view sees a vertex)
    color_views: int = option(
        32,
        "training views rendered for the vertex colours (0: colour along the normals only, without the dataset)",
        min=0,
        max=10000,
        group="mesh",
        needs="--mesh",
        metavar="N",
    )
    color_dirs: int = option(
        1,
        "directions averaged per colour of a vertex no view sees (1 = along the normal)",
        min=1,
        max=64,
        group="mesh",
        needs="--mesh",
        metavar="N",
    )
    every: int = option(1, "use every N-th training view", min=1, group="points", needs="--points", metavar="EVERY")
    stride: int = option(
        1, "use every N-th pixel in each direction", min=1, max=4096, group="points", needs="--points", metavar="STRIDE"
    )
    acc_min: float = option(
        0.5,
        "keep pixels with opacity above this",
        min=0,
        max=0.999,
        group="points",
        needs="--points",
        metavar="ACC_MIN",
    )
    crop: bool = option(True, "keep points outside the scene box", negated=True, group="points", needs="--points")
