"""nerfkit: phone photos to neural radiance fields, practical on a CPU.

The course API lives here under its familiar names; see :mod:`nerfkit.cameras` for the
one camera convention (OpenCV axes, pixel centres at +0.5).
"""

from .cameras import Rays, pixel_to_camera, pixel_to_ray, transform
from .fields.encoding import positional_encoding
from .render.sampling import sample_along_rays
from .render.volrend import volrend

__version__ = "0.1.0"

__all__ = [
    "Rays",
    "pixel_to_camera",
    "pixel_to_ray",
    "positional_encoding",
    "sample_along_rays",
    "transform",
    "volrend",
]
