"""The image fit's report: a fit's PSNR and speed, or each run of a sweep, and what was written."""

from __future__ import annotations

from typing import Any


def fit_report(result: Any, eval_every: int) -> str:
    """What :func:`~nerfkit.commands.tools.fit_image`'s ``result`` fitted and wrote (``eval_every``:
    the steps between the curve's evaluations)."""
    if result.sweep:
        runs = [
            f"{e['label']:30s} PSNR {e['final_psnr_db']:6.2f} dB  {e['steps_per_s']:6.1f} steps/s" for e in result.sweep
        ]
        n = len(runs)
        return "\n".join(
            [*runs, f"wrote {result.out}/sweep_grid.png, sweep_psnr.png, sweep.json and {n} run folder{'s' * (n != 1)}"]
        )
    m = result.metrics
    lines = [f"interrupted at step {m['steps']}: what was fitted is written"] if result.interrupted else []
    lines += [
        f"final PSNR {m['final_psnr_db']:.2f} dB (every pixel, {m['image_width']}x{m['image_height']}) after "
        f"{m['steps']} steps; {m['steps_per_s']:.1f} steps/s on {m['device']} ({m['precision']}), "
        f"{m['train_seconds']:.1f} s training + {m['eval_seconds']:.1f} s evaluation",
        f"curve: {m['curve']['note']}, every {eval_every} steps",
        f"wrote {result.out}/psnr.png, progression.png, final.png, metrics.json, config.json",
    ]
    return "\n".join(lines)
