"""Estimators: which samples along a ray are worth evaluating (nerfacc's estimators).

:class:`~nerfkit.estimators.occupancy.OccupancyEstimator`: a binary occupancy grid over a
:class:`~nerfkit.render.box.GridBox` that owns its buffers and its refresh, shared by the
``vanilla`` and ``fast`` models.
"""
