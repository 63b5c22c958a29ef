"""Options of the ``fast`` model (:class:`FastConfig`) and the defaults that depend on the scene."""

from __future__ import annotations

from dataclasses import dataclass

from ..config import check_ranges, option
from ..errors import fail
from ..fields.grid import MAX_GRID_SIDE, MAX_GRID_VERTICES
from .base import RGB_LOSSES

MAX_STAGE_RAYS = 64  # --stage-rays: the largest multiple of --batch-rays


def comma_ints(text: str) -> list[int]:
    """``"32, 64,128"`` -> ``[32, 64, 128]`` (empty items skipped); ValueError for anything else."""
    return [int(s) for s in text.split(",") if s.strip()]


# (resolutions, upsample steps) of the coarse-to-fine stages when the options are unset
BASE_STAGES = ("32,64,128,192", "60,300,2000")
# ... and for an object scene (not a capture, not forward-facing) whose photos have more
# pixels than this: one more stage, for the finer detail (lego 400x400, 5 minutes: 30.84
# -> 31.15 dB; lego 200x200 holds no detail finer than the 192 grid)
FINE_STAGES = ("32,64,128,192,256", "60,300,2000,3500")
FINE_STAGE_PIXELS = 100_000


# A capture's box follows its object (--box-follows): at each growth after the first, each
# face of the box that the object reaches (faces_reached) moves out by this share of the
# box's size along its axis, within the scene's sphere (a thin part of the object with no
# sparse points on it lies outside a box made from the points). A vertex is solid for that when
# its density makes a voxel of the grid this opaque (scale-free). At an early growth a thin
# part crossing a face already reaches 10%, while haze that later training clears reaches 5%
# but not 10% (benchmarks/capture_real.py --photos 30).
BOX_FOLLOW = 0.5
BOX_FOLLOW_OPACITY = 0.1
# ... at growths in the first half of the run only: what the new space starts with must
# have the steps to be carved
BOX_FOLLOW_UNTIL = 0.5


# weight of the table cover prior on few-photo captures that show no floor past the table's edge
TABLE_COVER_WEIGHT = 0.05


@dataclass
class FastConfig:
    """Options of the ``fast`` model."""

    resolutions: str = option(
        BASE_STAGES[0],
        "grid sizes of the coarse-to-fine stages, as the side of a cube with "
        "as many vertices (comma-separated; default: 32,64,128,192, and a fifth stage "
        f"of 256 for object scenes with photos over {FINE_STAGE_PIXELS // 1000}k pixels, "
        "such as lego at 400x400)",
    )
    upsample_steps: str = option(
        BASE_STAGES[1],
        "steps at which the grid grows to the next size (one fewer than "
        "--resolutions; default: 60,300,2000, and 3500 with the fifth stage); a "
        "growth with fewer steps left than 5% of those done is skipped",
    )
    stage_rays: str = option(
        "1,1,2,4",
        "rays per training step at each stage, as multiples of --batch-rays "
        "(comma-separated; later stages take the last): a finer grid has more vertices to "
        "share each step's rays, and fewer, fuller steps beat more, noisier ones (see "
        "BENCHMARKS.md)",
    )
    sh_degree: int = option(1, "spherical-harmonic degree of the view-dependent colour (0, 1 or 2)", min=0, max=2)
    # (below a hundredth of a voxel a ray's samples outgrow any memory before they add detail)
    step_ratio: float = option(0.5, "distance between samples along a ray, in voxels", min=0.01, max=4.0)
    init_alpha: float = option(1e-4, "opacity of one sample of the initial, near-empty density", above=0, max=0.5)
    occ_alpha: float = option(1e-2, "cells whose largest sample opacity is below this are skipped", above=0, max=0.5)
    occ_every: int = option(16, "steps between occupancy-grid refreshes", min=1)
    occ_start: int = option(4, "first step with empty-space skipping (all cells are sampled before)", min=1)
    occ_warmup: int = option(
        64,
        "until this step the occupancy is refreshed every --occ-start steps (carving "
        "empty space quickly while every step is still expensive)",
        min=0,
    )
    coarse_factor: int = option(
        8, "block size (in cells) of the coarse occupancy used to leap empty space", min=1, max=64
    )
    early_stop_eps: float = option(1e-4, "stop a ray once its transmittance is below this", min=0, max=0.5)
    colour_lr_ratio: float = option(1.0, "learning rate of the colour coefficients relative to --lr", min=0)
    adam_eps: float = option(1e-15, "Adam epsilon", above=0)
    shrink_box: bool = option(True, "at the first growth, shrink the box around where opaque training rays end")
    box_follows: bool = option(
        True,
        "with --table: at each growth after the first in the first half of the run, "
        "move out each face of the box that the object reaches, by "
        f"{BOX_FOLLOW:g} of the box's size (a thin part the sparse points missed, such as "
        "a sword, is otherwise cut off at the box)",
    )
    box_pad: int = option(3, "margin around the shrunken box, in voxels (plus 5% of its size)", min=0)
    learn_background: bool = option(
        False,
        "learn what rays see outside the box (a colour per direction) "
        "instead of the --background colour: for real photos, whose background is "
        "a room, not a flat colour",
    )
    room_shells: int = option(
        0,
        "with --learn-background: textured spheres around the cameras (each "
        "--room-ratio times the last) that hold the room with its parallax, in front "
        "of the colour per direction",
        min=0,
        max=16,
    )
    room_ratio: float = option(2.5, "radius of each room shell over the one inside it", above=1.0)
    room_resolution: int = option(
        1024,
        "texels around each room shell (half as many from bottom to top); 512 halves a "
        "capture's model file and scored within 0.07 dB of 1024 on five captures (BENCHMARKS.md)",
        min=8,
        max=4096,
    )
    room_lr_ratio: float = option(0.2, "learning rate of the room shells relative to --lr", min=0)
    table: bool = option(
        False,
        "rays stop at the scene's table plane (a tag capture's tag plane, where `poses` put it), which shows a "
        "learned texture: the box then holds only the object",
        default_help="on for capture datasets with a table plane, else off",
    )
    table_gloss: bool = option(
        False,
        "with --table: the table also mirrors its surroundings (a learned "
        "glossiness per texel mixes its colour with a small learned map of what "
        "lies along the reflected ray), for varnished tables and paper with a sheen, "
        "whose look changes with the view",
    )
    table_relief: bool = option(
        False,
        "with --table: the table also learns a height per texel (a sheet of paper that curls, "
        "a tag's plane a little off the table's), where rays then meet it",
    )
    table_tag_texels: int = option(
        0,
        "with --table: a fine colour texture of this many texels a side over each printed tag's "
        "square doubled (the tag, its border and the sheet's edge), on top of the table's (0: "
        "none; captures with tags: the finest power of two whose texel is at least the side of "
        "table one pixel sees, at most 256)",
        min=0,
        max=1024,
    )
    floor: bool = option(
        True,
        "with --table and --learn-background: a second textured plane for the floor seen "
        "beyond the table's edge, when the dataset's sparse points show one (a plane parallel "
        "to the table, well under it)",
    )
    table_resolution: int = option(
        512,
        "texels per side of the table texture (512: a texel of 1.7-1.9 mm on the benchmark "
        "captures, 1.4-2.9 pixels' footprint; 1024 sharpened one floor's grain and lost on "
        "four other captures: benchmarks/table_footprint.py, BENCHMARKS.md)",
        min=2,
        max=MAX_GRID_SIDE,
    )
    table_lr_ratio: float = option(
        0.2,
        "learning rate of the table texture relative to --lr (a texel is seen by few "
        "rays, and each sparse Adam step moves it by about the learning rate)",
        min=0,
    )
    opacity_weight: float = option(
        0.005,
        "with --table: weight of the mean opacity of the box in the loss, so that "
        "what the table and the room explain is not copied into clouds of density",
        min=0,
    )
    table_cover_weight: float = option(
        0.0,
        "with --table: weight of a prior that each spot of the table "
        "plane is table (opaque) or not (past the table's edge: clear), "
        "4 c (1 - c) of the light c it lets through, on the rays that reach "
        "it, against a table that blends a little of the room into each "
        "photo in blotches when few photos see each spot. It holds the "
        "plane opaque where the photos show a floor past the table's edge, "
        "and many photos average the blotches out. Default: "
        f"{TABLE_COVER_WEIGHT:g} on captures with fewer than 30 training "
        "photos whose sparse points show no floor under the table, else 0",
        min=0.0,
    )
    table_cover_start: float = option(
        0.0,
        "with --table-cover-weight: the share of the run after which the prior "
        "applies, so that the coverage first learns where the table ends",
        min=0.0,
        max=1.0,
    )
    distortion_weight: float = option(
        0.0,
        "weight of mip-NeRF 360's distortion loss (per ray, distances in "
        "units of the scene radius, in NDC in the fraction of the way from the near plane to "
        "infinity; with --table the table counts as the "
        "surface behind the box): it gathers each ray's weight onto one "
        "surface, against haze and floaters",
        min=0.0,
    )
    points_weight: float = option(
        0.0,
        "weight of the sparse points' sight lines, when the dataset records "
        "which train photos saw each point (nerfkit poses does): the ray from a "
        "photo's camera to a point it saw is empty up to the point and, for a "
        "point on the object, stopped just past it (as DS-NeRF supervises depth), "
        "so fur and fabric train solid instead of half see-through",
        min=0.0,
    )
    rgb_loss: str = option(
        "mse",
        "photometric loss: mse, or charbonnier (sqrt(e^2 + 1e-6), as mip-NeRF "
        "360), which lets pixels no consistent scene explains (the photographer's "
        "shadow, a moving reflection) pull no harder than small errors (on a clean "
        "synthetic object mse scores higher)",
        choices=list(RGB_LOSSES),
    )
    transient_quantile: float = option(
        0.0,
        "trim transients from the photometric loss (RobustNeRF-style): a ray whose error, "
        "less its photo's mean error, ranks above this quantile of its batch's (e.g. 0.8), "
        "in a neighbourhood of its photo where most rays drawn so far did too, gets "
        "weight 0 (the photographer's shadow on the table in some photos); a lone bad "
        "pixel among good ones (an edge, fine texture) keeps its weight; 0: off",
        min=0.0,
        max=1.0,
    )
    transient_start: float = option(
        0.2,
        "with --transient-quantile: the share of the run before any ray is trimmed "
        "(the scene must first be fitted for errors to tell transients apart)",
        min=0.0,
        max=1.0,
    )
    # Retired flags (kept as settings, off, for older runs' config.json and Python callers; see
    # BENCHMARKS.md "why the defaults are what they are"): --tv-weight and --tv-colour (every
    # weight tried cost PSNR), --near-grad (no gain held up, and it did not remove haze),
    # --distortion-table (it painted a low object onto the table).
    tv_weight: float = option(
        0.0,
        "weight of the total variation of the grid's density (as Plenoxels), on the "
        "vertices this step's rays touched: pulls each toward its neighbours, against "
        "density that few rays pin down (floaters, edges painted above a surface); 0: off (the "
        "default: see BENCHMARKS.md)",
        min=0.0,
        cli=False,
    )
    tv_colour: float = option(
        0.1,
        "with --tv-weight: the colour coefficients' total variation weight, relative to the density's",
        min=0.0,
        cli=False,
    )
    tv_view_weight: float = option(
        0.0,
        "weight of the total variation of the view-dependent colour alone "
        "(the spherical harmonics above degree 0), on the vertices each step's "
        "rays touched: a few photos pin down each vertex's colour from a few "
        "directions only, and its view-dependent part is otherwise free to "
        "sparkle in new views",
        min=0.0,
    )
    distortion_table: bool = option(
        False,
        "with --table, the distortion loss counts the table as the surface "
        "behind each ray, so haze in front of the table costs by its distance to it "
        "(clears haze, but a low object may be painted onto the table instead)",
        cli=False,
    )
    space: str = option(
        "auto",
        "where the grid lives: a box around the scene, or the normalised device "
        "coordinates of the mean camera (ndc: from the near plane to infinity, for forward-facing "
        "scenes such as LLFF captures); auto picks ndc when every camera looks about the same way",
        choices=["auto", "box", "ndc"],
    )
    ndc_depth_scale: float = option(
        1.0,
        "in NDC: the disparity axis is scaled by this before the grid's cubic voxels "
        "are laid over it (1: cubes in NDC; below 1: fewer vertices along the depth and, "
        "for the same vertex count, more across the view, where a forward-facing "
        "scene's detail is, and fewer samples a ray)",
        above=0.0,
        max=4.0,
    )
    ndc_square_pixels: bool = option(
        False,
        "in NDC: stretch the grid across by the photos' width over their height, so that a "
        "voxel spans as many pixels across as down (NDC's X and Y both span the photo, so a "
        "cube of NDC spans more pixels across a landscape photo than down)",
    )
    object_box: bool = option(
        True,
        "start from the box around the object that the dataset's sparse points "
        "give (points above the table that at least half the training photos frame), "
        "when it has them, instead of the bounding sphere's",
    )
    object_box_margin: float = option(
        0.0,
        "widen the object's box on every side by this share of its size (within the "
        "bounding sphere's box; default: 0, and 0.65 for a capture whose photos show no more "
        "detail on the object than on its table: a plain object frays in a tight box)",
        min=0.0,
    )
    near_grad: float = option(
        0.0,
        "damp the gradients of samples nearer to the camera than this fraction of the "
        "farthest camera's distance from the centre, by (distance / that)^2 (\"Floaters "
        'No More"), against floaters in front of the cameras (0: off)',
        min=0.0,
        max=10.0,
        cli=False,
    )
    sparse_from: int = option(
        100,
        "grids with at least this many vertices a side store only the vertices near "
        "occupied cells (memory follows the content); smaller grids are stored whole",
        min=2,
    )
    sparse_margin: int = option(
        2,
        "cells of the grid before a growth kept around its occupied cells in the grown "
        "sparse grid (density can appear only where vertices are stored)",
        min=0,
        max=16,
    )
    kernels: str = option(
        "auto", "auto (compiled numba on the CPU when available), numba, or torch", choices=["auto", "numba", "torch"]
    )

    def validate(self) -> FastConfig:
        """Its ranges, and the stages and ray factors its strings spell (refused as flags are)."""
        check_ranges(self)
        self.stages()
        self.stage_ray_factors()
        return self

    def stages(self) -> tuple[list[int], list[int]]:
        """``(sizes, steps)``: grid size of each stage and the steps at which stages start."""
        resolutions = BASE_STAGES[0] if self.resolutions is None else self.resolutions
        upsample_steps = BASE_STAGES[1] if self.upsample_steps is None else self.upsample_steps
        try:
            sizes, steps = comma_ints(resolutions), comma_ints(upsample_steps)
        except ValueError:
            raise fail("--resolutions/--upsample-steps", "expected comma-separated integers") from None
        if not sizes or min(sizes) < 4:
            raise fail("--resolutions", f"'{resolutions}' needs sizes >= 4")
        if any(b < a for a, b in zip(sizes, sizes[1:])):  # a stage upsamples the grid, or keeps it (a box moved)
            raise fail("--resolutions", f"'{resolutions}': a stage's grid must not be smaller than the one before")
        if max(sizes) ** 3 > MAX_GRID_VERTICES:  # a size is the side of a cube of vertices
            raise fail(
                "--resolutions",
                f"'resolutions' is '{resolutions}': sizes above "
                f"{round(MAX_GRID_VERTICES ** (1 / 3))} make grids too large to allocate",
                "Use smaller sizes",
            )
        steps = steps[: len(sizes) - 1]
        if len(steps) != len(sizes) - 1 or steps != sorted(steps):
            raise fail("--upsample-steps", f"needs {len(sizes) - 1} increasing steps for {len(sizes)} resolutions")
        return sizes, steps

    def stage_ray_factors(self) -> list[int]:
        """``--stage-rays`` as integers >= 1, one per stage from the first."""
        try:
            factors = comma_ints(self.stage_rays)
        except ValueError:
            factors = []
        if not factors or min(factors) < 1 or max(factors) > MAX_STAGE_RAYS:
            raise fail(
                "--stage-rays",
                f"'{self.stage_rays}' should be comma-separated integers from 1 to {MAX_STAGE_RAYS}, e.g. 1,1,2,4",
            )
        return factors
