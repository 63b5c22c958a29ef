"""Datasets: the Scene type, file formats, and ray batches for training."""

from .scene import Scene, Views

__all__ = ["Scene", "Views"]
