"""Structure-from-motion: camera poses from photos alone (pycolmap), see :mod:`.colmap`.

Entry point for ``nerfkit poses --method colmap``: :func:`sfm_dataset`.
"""

from .colmap import SfmReport, SfmResult, run_sfm
from .dataset import build_dataset, sfm_dataset
from .frame import align_reconstruction, compare_poses, umeyama

__all__ = [
    "SfmReport",
    "SfmResult",
    "align_reconstruction",
    "build_dataset",
    "compare_poses",
    "run_sfm",
    "sfm_dataset",
    "umeyama",
]
