"""A run's metrics rows and report files as functions of their data (nerfkit.train.reports)."""

from __future__ import annotations

import csv
import json

import numpy as np

from nerfkit.data.scene import Views
from nerfkit.train.reports import eval_rows, scored_at, train_row, val_row, write_metrics


def val_views(n: int, size: int = 8) -> Views:
    c2w = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
    K = np.tile(np.eye(3, dtype=np.float32), (n, 1, 1))
    return Views(c2w, K, size, size)


def test_a_periodic_evaluation_is_one_row_and_a_final_one_ends_the_periodic_curve_too():
    val = val_views(4)
    rows, message = eval_rows(10, 1.23456, [20.0, 22.0], 16, False, val, 2, 1 << 30)
    assert [(r["step"], r["seconds"], r["psnr"], r["views"], r["pixels"]) for r in rows] == [(10, 1.235, 21.0, 2, 16)]
    assert "first 2 of 4 views, 16 pixels each" in message
    rows, message = eval_rows(20, 2.0, [20.0, 22.0, 24.0, 26.0], 64, True, val, 2, 1 << 30)
    assert [(r["views"], r["psnr"]) for r in rows] == [(2, 21.0), (4, 23.0)]
    assert "all 4 views; the first 2, as evaluated during training: 21.00 dB" in message


def test_an_evaluation_counts_as_final_only_on_every_view_whole():
    val = val_views(2)
    rows = [train_row(5, 1.0, 0.1, 20.0, 256), val_row(5, 1.0, 20.0, 1, 64)]
    assert scored_at(rows, 5, val, final=False) and not scored_at(rows, 5, val, final=True)
    assert not scored_at(rows, 6, val, final=False)
    assert scored_at([{"step": 5, "split": "val"}], 5, val, final=True)  # older runs' rows


def test_metrics_files_hold_the_rows(tmp_path):
    rows = [train_row(10, 1.0, 0.5, 18.0, 256), val_row(10, 1.0, 19.0, 2, 64)]
    write_metrics(tmp_path, rows, 10, 1.0, True, ["a note"])
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["step"] == 10 and saved["finished"] is True and saved["notes"] == ["a note"]
    assert saved["rows"][0]["rays"] == 256 and saved["rows"][1]["psnr"] == 19.0
    with open(tmp_path / "metrics.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["split"] for r in table] == ["train", "val"] and table[0]["rays"] == "256" and table[1]["views"] == "2"
