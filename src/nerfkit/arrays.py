"""numpy arrays in, numpy arrays out, for the course functions (they compute in torch)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import torch

F = TypeVar("F", bound=Callable[..., Any])


def _to_numpy(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    if isinstance(value, tuple):
        return tuple(_to_numpy(v) for v in value)
    return value


def accepts_numpy(fn: F) -> F:
    """Let ``fn`` take numpy arrays where it takes tensors.

    Each numpy array argument becomes a tensor of its dtype (shared memory, no copy). When
    no argument was a tensor, the tensors returned (alone or in a tuple) come back as numpy
    arrays; given any tensor, the results stay tensors.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        given = [*args, *kwargs.values()]
        if not any(isinstance(a, np.ndarray) for a in given):
            return fn(*args, **kwargs)
        torch_given = any(isinstance(a, torch.Tensor) for a in given)

        def convert(a: Any) -> Any:
            return torch.from_numpy(np.ascontiguousarray(a)) if isinstance(a, np.ndarray) else a

        out = fn(*[convert(a) for a in args], **{k: convert(v) for k, v in kwargs.items()})
        return out if torch_given else _to_numpy(out)

    return wrapper  # type: ignore[return-value]
