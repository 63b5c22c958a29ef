"""What a model renders for a batch of rays: one dataclass every model returns, every loss
term reads and the trainer, evaluation and viewers draw."""

from __future__ import annotations

from dataclasses import dataclass, field

from torch import Tensor


@dataclass
class RenderOutput:
    """What a model returns for n_rays rays.

    Attributes:
        rgb: (n_rays, 3) colour, background already composited.
        depth: (n_rays,) expected depth sum(w_i t_i) (unnormalised; divide by acc for
            the depth of the surface that was hit).
        acc: (n_rays,) opacity sum(w_i).
        n_samples: number of field evaluations spent (for throughput figures).
        extras: model-specific tensors the model's own loss uses (e.g. coarse rgb).
        scene_depth, scene_acc: (n_rays,) as ``depth`` and ``acc`` but of everything the
            rays meet, the surfaces a model draws behind its volume included (a capture's
            table and room: the light the volume passes goes to the one surface it meets,
            :func:`~nerfkit.render.layers.layers_depth`); None when it draws none
            (then ``depth`` and ``acc`` say it) and while training.
    """

    rgb: Tensor
    depth: Tensor
    acc: Tensor
    n_samples: int = 0
    extras: dict[str, Tensor] = field(default_factory=dict)
    scene_depth: Tensor | None = None
    scene_acc: Tensor | None = None
