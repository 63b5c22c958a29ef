"""What a trained model produces: whole rendered images (in chunks) and orbit/depth videos.

This layer sits above the models; :mod:`nerfkit.render` below them holds only the pure
rendering math (volume rendering, sampling, occupancy) that the models use.
"""
