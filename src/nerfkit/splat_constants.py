"""The constants of 3D Gaussian splatting, in one place: plain Python numbers, no torch.

The torch reference (:mod:`nerfkit.kernels.splat_reference`, and the grid's SH basis in
:mod:`nerfkit.kernels.reference`), the compiled kernels (:mod:`nerfkit.kernels.splat_numba`,
which must not need torch) and the splat files (:mod:`nerfkit.splat_files`) all import them
from here, so they cannot drift apart.

Where they come from:

* ``SH_C0`` .. ``SH_C3``: the real spherical-harmonic basis' normalisations up to degree 3,
  as INRIA 3DGS's ``utils/sh_utils.py`` (and gsplat's SH kernels) write them, signs included
  (``SH_C0 = 1 / (2 sqrt(pi))``, Y_00). The grid field uses the same basis up to degree 2.
* ``FOV_CLIP``: the view-space ``x / z`` and ``y / z`` are clamped to 1.3 x the half field of
  view before the EWA Jacobian (INRIA's ``limx = 1.3 * tan_fovx``).
* ``DILATION``: 0.3 px^2 added to the 2D covariance's diagonal (INRIA's low-pass filter).
* ``TILE``: tiles of 16 x 16 pixels (INRIA's ``BLOCK_X``, ``BLOCK_Y``; gsplat's default).
* ``ALPHA_MIN``, ``ALPHA_MAX``, ``T_MIN``: a Gaussian is skipped at a pixel where its alpha is
  below 1/255, alpha is clamped at 0.99, and compositing stops before the transmittance
  would fall below 1e-4 (INRIA's forward and backward rasterizer).
"""

from __future__ import annotations

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
FOV_CLIP = 1.3
DILATION = 0.3
TILE = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
