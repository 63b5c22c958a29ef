"""From phone photos to a posed NeRF dataset: ArUco tags, calibration, poses, undistortion.

Pipeline (see the ``calibrate``, ``poses`` and ``dataset`` commands):

1. :mod:`.aruco` detects tags (on a downscaled copy, corners refined at full resolution)
   and describes tag sheets (:class:`~.aruco.Layout`: explicit layouts or OpenCV boards).
2. :mod:`.calibrate` estimates ``K`` and distortion from photos of a tag sheet, estimating
   the sheet's layout when it is not given, rejecting outlier photos and checking sanity.
3. :mod:`.poses` gives each object photo a camera-to-world pose in the tag's frame.
4. :mod:`.dataset` undistorts, crops, resizes and splits the posed photos and writes a
   course npz and a nerfstudio ``transforms.json``.

Pixel coordinates inside this package are OpenCV's (pixel centres at integers), because
``K`` and distortion go straight into OpenCV; :mod:`.dataset` is the one place that converts
to nerfkit's convention (pixel centres at +0.5, see :mod:`nerfkit.cameras`).
"""
