"""Helpers shared by the test modules (not a test module itself).

The test folders hold no ``__init__.py``: pytest puts ``tests/`` (the folder of the
root ``conftest.py``) on ``sys.path``, so every test module imports these as
``from _helpers import ...``, and test file names are unique across the folders.
"""

import contextlib
import io
import warnings

import numpy as np


def frame_error(estimate, truth, target_shape, n=17):
    """Largest error (target pixels) of ``estimate`` over the whole target frame.

    For a grid of target pixels ``p``: ``max |T_est(T_true^-1(p)) - p|``.
    Both transforms may be models (with ``.matrix``) or 3x3 matrices.
    """
    m_est = estimate.matrix if hasattr(estimate, "matrix") else np.asarray(estimate)
    m_true = truth.matrix if hasattr(truth, "matrix") else np.asarray(truth)
    ny, nx = target_shape
    gx, gy = np.meshgrid(np.linspace(-0.5, nx - 0.5, n), np.linspace(-0.5, ny - 0.5, n))
    p = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    r = p @ np.linalg.inv(m_true).T @ m_est.T
    return float(np.max(np.hypot(r[:, 0] - p[:, 0], r[:, 1] - p[:, 1])))


def run_cli(*args):
    """``astroalign-nd ARGS`` in this process: (exit code, stdout, stderr).

    The package's own warnings print as the command line prints them (one line on
    standard error), as in a process of its own; any other warning stays an error
    (the suite's ``filterwarnings = error``).  A few tests start a real process
    (signals, exit codes of ``python -m astroalign_nd.cli``); the rest use this.
    """
    from astroalign_nd import AstroalignWarning
    from astroalign_nd.cli import main

    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(err):
        warnings.filterwarnings("default", category=AstroalignWarning)
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def random_matrix(rng, transform_type, mirrored=False, frame=1000.0, scale_range=(0.6, 1.6),
                  stretch=0.15, shear=0.1, shift=150.0):
    """A source -> target matrix of the given type.

    Similarity and affine scales are drawn from ``scale_range``; affine adds a
    stretch of up to ``stretch`` and a shear of up to ``shear``.  The centre of
    a ``frame`` x ``frame`` field moves by at most ``shift`` px on each axis,
    so it stays inside the target field: the fields overlap.
    """
    rot = rng.uniform(-np.pi, np.pi) if transform_type != "translation" else 0.0
    scale = rng.uniform(*scale_range) if transform_type in ("similarity", "affine") else 1.0
    c, s = np.cos(rot), np.sin(rot)
    lin = scale * np.array([[c, -s], [s, c]])
    if transform_type == "affine":
        lin = lin @ np.array([[rng.uniform(1 - stretch, 1 + stretch), rng.uniform(-shear, shear)],
                              [0.0, rng.uniform(1 - stretch, 1 + stretch)]])
    if mirrored and transform_type != "translation":
        lin = lin @ np.diag([1.0, -1.0])
    m = np.eye(3)
    m[:2, :2] = lin
    centre = np.array([frame / 2, frame / 2])
    m[:2, 2] = centre - lin @ centre + rng.uniform(-shift, shift, 2)
    return m


# Points spanning a typical detector, with non-integer and negative values.
SAMPLE_XS = np.array([0.0, 1.0, -3.5, 123.456, 2047.0, 4095.75, -1000.0])
SAMPLE_YS = np.array([0.0, 2.0, 7.25, -45.5, 2047.0, 10.0, 3000.0])


def sample_linear_transforms(similarity_translation_y=-0.1):
    """One model of each linear type, plus a mirrored one of each that can mirror.

    Keys: ``translation``, ``euclidean``, ``euclidean-mirrored``, ``similarity``,
    ``similarity-mirrored``, ``affine``, ``affine-mirrored``.  Several matrix
    elements need all 17 significant digits; ``similarity_translation_y`` may be
    given one with an exponent (a FITS float card cannot hold either exactly).
    """
    import astropy.units as u

    from astroalign_nd.transforms import (AffineTransform, EuclideanTransform,
                                          SimilarityTransform, TranslationTransform)

    return {
        "translation": TranslationTransform(translation_x=12.345678901234567,
                                            translation_y=-7.0 / 3.0),
        "euclidean": EuclideanTransform(rotation=0.7 * u.rad, translation_x=-12.5,
                                        translation_y=3.0 / 7.0),
        "euclidean-mirrored": EuclideanTransform(rotation=-2.1 * u.rad, translation_x=100.0,
                                                 translation_y=-50.25, parity=-1),
        "similarity": SimilarityTransform(scale=1.0123456789, rotation=np.pi / 7 * u.rad,
                                          translation_x=1e3 / 3.0,
                                          translation_y=similarity_translation_y),
        "similarity-mirrored": SimilarityTransform(scale=0.5, rotation=3.0 * u.rad,
                                                   translation_x=-20.0, translation_y=5.5,
                                                   parity=-1),
        "affine": AffineTransform(a11=1.01, a12=0.02, a21=-0.03, a22=0.98,
                                  translation_x=4.0, translation_y=-9.0 / 11.0),
        "affine-mirrored": AffineTransform(a11=0.9, a12=0.1, a21=0.2, a22=-1.1,
                                           translation_x=-3.0, translation_y=2.0),
    }


class RadialTruth:
    """
    A known source -> target mapping: radial distortion about the frame's centre,
    then a rotation (degrees) and a shift.

    ``r' = r (1 + k r^2 / r2max)``, with ``k`` such that the corners (``r^2 =
    r2max``) move by ``corner_px``; called as ``truth(x, y) -> (x', y')``.
    """

    def __init__(self, shape, corner_px, rotation, shift=(7.0, -5.0)):
        ny, nx = shape
        self.c = np.array([(nx - 1) / 2.0, (ny - 1) / 2.0])
        self.r2max = float(np.sum(self.c ** 2))
        self.k = corner_px / np.sqrt(self.r2max)
        a = np.deg2rad(rotation)
        self.rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        self.shift = np.asarray(shift, float)

    def __call__(self, x, y):
        d = np.stack([np.asarray(x, float) - self.c[0], np.asarray(y, float) - self.c[1]])
        d = d * (1.0 + self.k * (d[0] ** 2 + d[1] ** 2) / self.r2max)
        out = np.tensordot(self.rot, d, axes=1)
        return out[0] + self.c[0] + self.shift[0], out[1] + self.c[1] + self.shift[1]


def write_sequence(folder, n_frames, seed, shape=(96, 96), n_stars=50, noise_sigma=5.0):
    """
    Write a simulated sequence as FITS files ``f0.fits``... in ``folder``.

    ``n_stars`` and ``noise_sigma`` (the sky noise; None: the simulator's
    default) go to `~astroalign_nd.simulate.simulate_sequence`.  Returns the
    paths (str), the first frame (the reference) first.
    """
    from astropy.nddata import CCDData

    from astroalign_nd.io import write_ccddata
    from astroalign_nd.simulate import simulate_sequence

    seq = simulate_sequence(shape, n_frames=n_frames, n_stars=n_stars, noise_sigma=noise_sigma,
                            seed=seed)
    paths = []
    for k, frame in enumerate(seq.frames):
        path = str(folder / f"f{k}.fits")
        write_ccddata(CCDData(np.asarray(frame.data), unit="adu"), path)
        paths.append(path)
    return paths


def count_calls(monkeypatch, owner, name):
    """Replace ``owner.name`` by a wrapper that counts its calls; return the count (a list).

    Each call appends its positional arguments to the list, then runs the real function.
    """
    calls = []
    real = getattr(owner, name)

    def counted(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(owner, name, counted)
    return calls


def edit_cards(*delete, **cards):
    """A change to a FITS header: delete the keywords ``delete``, then set ``cards``."""
    def change(header):
        for key in delete:
            del header[key]
        for key, value in cards.items():
            header[key] = value
    return change


def assert_header_refused(model, change, message):
    """The transform keywords of ``model``, once ``change``\\ d, are refused with ``message``."""
    import pytest

    from astroalign_nd.io import transform_from_header, transform_to_header

    header = transform_to_header(model)
    change(header)
    with pytest.raises(ValueError, match=message):
        transform_from_header(header)
