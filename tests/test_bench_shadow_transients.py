"""benchmarks/shadow_transients.py: the painted photographer's shadow and the shadowed copy of a
dataset (only its training photos change)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

_BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(_BENCH))
_spec = importlib.util.spec_from_file_location("shadow_transients", _BENCH / "shadow_transients.py")
st = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(st)


def test_shadow_rises_from_the_bottom_edge_and_spans_darkness_to_one():
    f = st.photographer_shadow(120, 160, np.random.default_rng(3), darkness=0.4)
    assert f.shape == (120, 160) and f.dtype == np.float32
    assert f.min() >= 0.4 - 1e-6 and f.max() <= 1.0 + 1e-6
    assert np.allclose(f[0], 1.0, atol=1e-4)  # the top row is lit
    bottom = f[-1]
    assert bottom.min() == pytest.approx(0.4, abs=0.02)  # full shadow at the bottom edge
    assert np.allclose(bottom[[0, -1]], 1.0, atol=0.02)  # the corners lie outside (centre in 20-80%)
    # darker lower down, column by column through the shadow's centre
    col = int(np.argmin(bottom))
    assert np.all(np.diff(f[:, col]) <= 1e-5)


def test_add_shadows_changes_the_share_asked_and_nothing_else():
    rng = np.random.default_rng(0)
    images = rng.integers(60, 255, size=(10, 40, 50, 3), dtype=np.uint8)
    out, which = st.add_shadows(images, 0.3, 0.5, np.random.default_rng(1))
    assert len(which) == 3 and np.all(np.diff(which) > 0)
    changed = [i for i in range(10) if not np.array_equal(out[i], images[i])]
    assert changed == which.tolist()
    assert np.all(out <= images)  # a shadow only darkens
    i = which[0]
    assert (out[i, -1].astype(float) / images[i, -1]).min() < 0.6  # and it is dark at the bottom
    again, which2 = st.add_shadows(images, 0.3, 0.5, np.random.default_rng(1))
    assert np.array_equal(again, out) and np.array_equal(which2, which)


def test_shadowed_copy_keeps_every_other_array(tmp_path):
    rng = np.random.default_rng(2)
    arrays = {
        "images_train": rng.integers(50, 255, size=(4, 16, 20, 3), dtype=np.uint8),
        "images_val": rng.integers(50, 255, size=(2, 16, 20, 3), dtype=np.uint8),
        "c2ws_train": rng.normal(size=(4, 4, 4)).astype(np.float32),
        "names_train": np.array([f"p{i}.jpg" for i in range(4)]),
    }
    src = tmp_path / "in.npz"
    np.savez(src, **arrays)
    before = src.read_bytes()
    which = st.shadowed_copy(src, tmp_path / "out" / "s.npz", 0.5, 0.5, seed=0)
    assert src.read_bytes() == before  # the input is not rewritten
    with np.load(tmp_path / "out" / "s.npz") as d:
        assert set(d.files) == set(arrays)
        for k in ("images_val", "c2ws_train", "names_train"):
            assert np.array_equal(d[k], arrays[k])
        diff = [i for i in range(4) if not np.array_equal(d["images_train"][i], arrays["images_train"][i])]
    assert diff == which.tolist() and len(which) == 2
