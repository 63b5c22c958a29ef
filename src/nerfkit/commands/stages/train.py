"""The training stage's report: the line a training run ends with."""

from __future__ import annotations


def summary_line(result) -> str:
    """The line `nerfkit train` ends with, for a :class:`nerfkit.api.TrainResult`."""
    summary = f"run: {result.run_dir}  steps: {result.steps}  training time: {result.train_seconds:.0f} s"
    if result.val_psnr is not None:
        summary += f"  val PSNR: {result.val_psnr:.2f} dB"
    return summary
