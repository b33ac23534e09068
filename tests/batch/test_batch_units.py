# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Unit tests of `register_batch` on in-memory frames with known transforms:
what it recovers (in pixels), how it reports a bad frame and goes on, and
that it never replaces an output unless asked to.
"""

import os
from pathlib import Path

import numpy as np
import pytest
from astropy.nddata import CCDData
from astropy.table import Table

from astroalign_nd import find_transform, register_batch
from astroalign_nd.simulate import draw_fluxes, simulate_image
from astroalign_nd.transforms import SimilarityTransform

from _helpers import frame_error

SHAPE = (160, 160)
#: (rotation deg, scale, shift x, shift y) of each frame, source to target pixels:
#: a rotation and scale about the frame's centre, then the shift.
TRUTHS = [(12.0, 1.0, 6.5, -4.25), (-30.0, 1.03, -9.0, 3.5), (95.0, 0.98, 4.0, 8.0)]


@pytest.fixture(scope="module")
def field():
    """A target frame and frames whose pixels map onto it by the known ``TRUTHS``."""
    rng = np.random.default_rng(7)
    n = 150
    x, y = rng.uniform(-40, SHAPE[1] + 40, n), rng.uniform(-40, SHAPE[0] + 40, n)
    flux = draw_fluxes(n, flux_range=(2e3, 2e5), seed=8)
    target = simulate_image(SHAPE, x, y, flux, seed=9)
    frames, truths = [], []
    for k, (rot, scale, dx, dy) in enumerate(TRUTHS):
        c = np.array([SHAPE[1] - 1, SHAPE[0] - 1]) / 2.0
        a = np.radians(rot)
        rc = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ c
        t = SimilarityTransform(scale=scale, rotation=rot, translation_x=c[0] - rc[0] + dx,
                                translation_y=c[1] - rc[1] + dy)
        sx, sy = t.inverse(x, y)  # a star at target (x, y) sits at source T^-1(x, y)
        frames.append(simulate_image(SHAPE, sx, sy, flux, seed=20 + k))
        truths.append(t)
    return target, frames, truths


def test_known_transforms_recovered_in_pixels(field):
    target, frames, truths = field
    result = register_batch(frames, target)
    assert [f.status for f in result.frames] == ["registered"] * len(frames)
    for f, frame, truth in zip(result.frames, frames, truths):
        assert frame_error(f.transform, truth, SHAPE) < 0.15  # over the whole frame, px
        assert f.ccd.shape == SHAPE
        assert f.quality["n_matches"] >= 20
        # One find policy: the batch finds exactly what find_transform finds.
        alone, _ = find_transform(frame, target)
        np.testing.assert_array_equal(f.transform.matrix, alone.matrix)


def test_bad_frames_are_reported_and_the_batch_goes_on(field):
    target, frames, truths = field
    catalog = Table({"x": [10.0, 50.0, 90.0, 30.0], "y": [20.0, 80.0, 40.0, 120.0]})
    sources = [frames[0], np.zeros(SHAPE), catalog, np.ones((5,)), frames[1]]
    result = register_batch(sources, target)
    assert [f.status for f in result.frames] == [
        "registered", "failed", "failed", "failed", "registered"]
    assert result.frames[1].error.startswith("TooFewSourcesError: ")
    assert result.frames[2].error.startswith("TypeError: ")
    assert "catalog" in result.frames[2].error  # a catalog cannot be resampled
    assert result.frames[3].error.startswith(("ValueError: ", "TypeError: "))
    assert all(f.ccd is None for f in result.failed)
    for i, truth in ((0, truths[0]), (4, truths[1])):
        assert frame_error(result.frames[i].transform, truth, SHAPE) < 0.15
    assert "2 of 5 frames registered, 3 failed" in result.summary()


def test_no_overwrite_without_overwrite_true(field, tmp_path):
    target, frames, truths = field
    out = tmp_path / "out"
    first = register_batch(frames[:2], target, output_dir=out)
    paths = [f.output for f in first.frames]
    before = [Path(p).read_bytes() for p in paths]

    again = register_batch(frames[:2], target, output_dir=out)
    assert [f.status for f in again.frames] == ["failed", "failed"]
    assert all("FileExistsError" in f.error and "overwrite=True" in f.error
               for f in again.frames)
    assert [Path(p).read_bytes() for p in paths] == before  # not touched
    assert sorted(os.listdir(out)) == sorted(os.path.basename(p) for p in paths)

    replaced = register_batch(frames[:2], target, output_dir=out, overwrite=True)
    assert [f.status for f in replaced.frames] == ["registered", "registered"]
    for f, truth in zip(replaced.frames, truths):
        assert frame_error(f.transform, truth, SHAPE) < 0.15
        assert CCDData.read(f.output).shape == SHAPE


def test_frames_are_not_modified(field):
    target, frames, _ = field
    copies = [f.copy() for f in frames[:1]]
    target_copy = target.copy()
    register_batch(frames[:1], target)
    np.testing.assert_array_equal(frames[0], copies[0])
    np.testing.assert_array_equal(target, target_copy)


def test_catalog_target_refused_before_any_work(tmp_path):
    catalog = Table({"x": [10.0, 50.0, 90.0], "y": [20.0, 80.0, 40.0]})
    with pytest.raises(TypeError, match="must be an image"):
        register_batch([np.zeros(SHAPE)], catalog, output_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()
