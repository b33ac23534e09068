# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Each frame is detected once per call, a frame met again never twice, and a
missing compiled extension is said once (`SlowKernelsWarning`).
"""

import warnings

import numpy as np
import pytest

import astroalign_nd.registration as registration
from astroalign_nd import Reference, conf, find_transform, register
from astroalign_nd import _kernels
from astroalign_nd.exceptions import SlowKernelsWarning, TransformNotFoundError
from astroalign_nd.simulate import simulate_pair


@pytest.fixture
def detections(monkeypatch):
    """The ``n_sources`` of every detection run by the registration module."""
    calls = []
    detect = registration.control_sources

    def counted(image, **kwargs):
        calls.append(kwargs["n_sources"])
        return detect(image, **kwargs)

    monkeypatch.setattr(registration, "control_sources", counted)
    return calls


def _pair(seed, **kwargs):
    return simulate_pair((256, 256), n_stars=120, rotation=25.0, translation=(6.0, -4.0),
                         seed=seed, **kwargs)


def _truth_error(t, pair):
    """Largest distance (px) between the found and true maps over the frame's corners."""
    xy = np.array([[0.0, 0.0], [255.0, 0.0], [0.0, 255.0], [255.0, 255.0]])
    m = np.asarray(pair.truth_matrix, float)
    found = np.asarray(t.matrix, float)
    diff = xy @ (found - m)[:2, :2].T + (found - m)[:2, 2]
    return float(np.max(np.hypot(diff[:, 0], diff[:, 1])))


def test_find_transform_and_register_detect_each_frame_once(detections):
    pair = _pair(1)
    t, _ = find_transform(pair.source, pair.target)
    assert _truth_error(t, pair) < 0.15
    assert len(detections) == 2
    detections.clear()
    register(pair.source, pair.target)
    assert len(detections) == 2


def test_reference_is_detected_once_over_several_sources(detections):
    pair = _pair(2)
    # Three exposures of one field onto one reference (other gains and skies).
    sources = [pair.source, 1.5 * pair.source, pair.source + 20.0]
    ref = Reference(pair.target)
    for src in sources:
        t, _ = find_transform(src, ref)
        assert _truth_error(t, pair) < 0.15
    # The reference once, each source once.
    assert len(detections) == 1 + len(sources)


def test_smaller_count_is_taken_from_a_larger_detection(detections):
    pair = _pair(5)
    ref = Reference(pair.target)
    big = ref.stars(100)[0]
    small = ref.stars(25)[0]
    assert len(detections) == 1
    # The brightest first: the smaller list is the start of the larger one.
    np.testing.assert_array_equal(small, big[:len(small)])
    assert len(small) == 50


def test_refused_pair_detects_each_frame_once(detections):
    # Two unrelated sparse fields: every attempt of the search fails, and a
    # larger detection could find no star that the first one did not.
    a = simulate_pair((200, 200), n_stars=15, seed=11)
    b = simulate_pair((200, 200), n_stars=15, seed=12)
    with pytest.raises(TransformNotFoundError, match="no trustworthy transform"):
        find_transform(a.source, b.target)
    assert len(detections) == 2


def test_later_attempts_detect_once_more_at_the_largest_count(detections):
    # A small overlap: the 10 brightest stars of each frame are mostly
    # outside it, so the first attempt fails and later ones need more stars.
    # Each frame is detected again once, at the largest count of the search
    # (2 x max_sources stars), which serves every later attempt (and measures
    # only the candidates the first detection did not: see below).
    pair = simulate_pair((384, 384), n_stars=400, rotation=10.0, translation=(250.0, 200.0),
                         seed=0)
    t, _ = find_transform(pair.source, pair.target, n_sources=10, max_sources=40)
    assert _truth_error(t, pair) < 0.2
    assert sorted(detections) == [20, 20, 80, 80]


def test_missing_compiled_loops_are_said_once(monkeypatch):
    monkeypatch.setattr(_kernels, "HAVE_COMPILED", False)
    monkeypatch.setattr(_kernels, "_WARNED_SLOW", False)
    pair = _pair(6)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        find_transform(pair.source, pair.target)
        find_transform(pair.target, pair.source)
    slow = [w for w in caught if issubclass(w.category, SlowKernelsWarning)]
    assert len(slow) == 1
    message = str(slow[0].message)
    assert "slower" in message and "wheel" in message
    # Pointed at the caller's line, not inside the package.
    assert slow[0].filename == __file__


def test_no_warning_when_the_numpy_kernels_are_chosen(monkeypatch):
    # Built, but turned off by the user (conf.use_compiled): a choice, not a
    # missing install, so nothing to say (and this runs without the build too).
    monkeypatch.setattr(_kernels, "HAVE_COMPILED", True)
    monkeypatch.setattr(_kernels, "_WARNED_SLOW", False)
    monkeypatch.setattr(conf, "use_compiled", False)
    pair = _pair(8)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SlowKernelsWarning)
        find_transform(pair.source, pair.target)


@pytest.fixture
def detection_work(monkeypatch):
    """
    Per frame (a key of its pixels): the full-frame passes of detection run,
    and every candidate measured, with the width it was measured at.
    """
    from astroalign_nd.detection import daofind

    passes, measured = [], []

    def frame(data):
        return hash(np.ascontiguousarray(data[::7, ::5]).tobytes())

    stage1, rows = daofind._stage1, daofind._measure_rows

    def counted_stage1(data, *args):
        passes.append(frame(data))
        return stage1(data, *args)

    def counted_rows(data, cand, tiles, fwhm, *args):
        measured.extend((frame(data), fwhm, x, y) for x, y in zip(cand["x"], cand["y"]))
        return rows(data, cand, tiles, fwhm, *args)

    monkeypatch.setattr(daofind, "_stage1", counted_stage1)
    monkeypatch.setattr(daofind, "_measure_rows", counted_rows)
    return passes, measured


def test_escalating_refusal_measures_each_frame_once(detections, detection_work):
    # Two unrelated fields of 400 stars: every attempt fails, and the later
    # ones ask for 4 times as many stars of each frame as the first.
    a = simulate_pair((384, 384), n_stars=400, seed=21)
    b = simulate_pair((384, 384), n_stars=400, seed=22)
    src, dst = Reference(a.source), Reference(b.target)
    with pytest.raises(TransformNotFoundError, match="no trustworthy transform"):
        find_transform(src, dst)
    # Each frame asked twice: for the first attempt, then for the largest count.
    assert sorted(detections) == [100, 100, 400, 400]
    passes, measured = detection_work
    # ... but its full-frame passes ran once, and no candidate was measured
    # twice at one width: the second detection measured the ones it added.
    assert len(passes) == 2 and len(set(passes)) == 2
    assert len(measured) == len(set(measured))
    assert len({m[0] for m in measured}) == 2
    # And the stars are those of a detection made for the largest count at once.
    for ref, image in ((src, a.source), (dst, b.target)):
        fresh = Reference(image).stars(200)[0]
        np.testing.assert_allclose(ref.stars(200)[0], fresh, rtol=0, atol=1e-9)
