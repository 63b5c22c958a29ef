"""The pipeline from Python: calibrate, pose, train, render, evaluate, export, and capture
(all of them in a row); and the tools around it: tags, frames, convert, dataset, fit_image
and view. Every command has its function but ``demo`` (train, render and evaluate on the
bundled lego scene).

Each function takes typed keyword arguments named as the flags of its command
(``tag_size=0.06`` for ``--tag-size 0.06``; ``--no-X`` is ``X=False``, but ``--no-dataset`` is
``build_dataset=False`` and ``--dict`` is ``dictionary``; choices as strings; a command's option
groups are one settings object: ``settings=CalibrateConfig(...)``, ``pose_settings=PoseConfig(...)``,
``dataset_settings=DatasetConfig(...)``, ``fit_image(settings=FitImageConfig(...))``). Four names
differ from their command's: ``pose`` (``poses``), ``evaluate`` (``eval``), ``fit_image``
(``fit-image``) and ``resume`` (``train --resume``). Each function checks them as the
command line is checked, does the stage's work, prints the command's
report unless ``quiet=True``, and returns a typed result. The commands are these functions
behind a command line; ``nerfkit capture`` runs them in a row. Example::

    from nerfkit import api

    camera = api.calibrate("sheet_photos/", "camera.json", tag_size=0.04)
    poses = api.pose("object_photos/", "my_object/", tag_size=0.06, camera=camera.camera_path)
    run = api.train(poses.dataset_path, "runs/my_object", minutes=3)
    print(run.val_psnr, api.render(run.run_dir).videos)

    result = api.capture("clip.mp4", "my_object/", model="both")  # frames, SfM, NeRF and splat

    api.tags("tags.pdf", tag_size=0.04)  # the sheet to print
    api.convert("my_object/dataset.npz", "my_object_ns/")  # transforms.json and images/

The functions live in :mod:`nerfkit.commands.pipeline` and :mod:`nerfkit.commands.tools`,
beside the commands they share their checks with; this module is their public name.
"""

from __future__ import annotations

from .commands import pipeline as _pipeline
from .commands import tools as _tools
from .commands.pipeline import *  # noqa: F403 - this module is the pipeline's public name
from .commands.tools import *  # noqa: F403 - and the tools' around it

__all__ = [*_pipeline.__all__, *_tools.__all__]
