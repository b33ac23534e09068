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


def random_matrix(rng, transform_type, mirrored=False, frame=1000.0):
    """A source -> target matrix of the given type (modest shear for affine).

    The centre of a ``frame`` x ``frame`` field stays inside the target field.
    """
    rot = rng.uniform(-np.pi, np.pi) if transform_type != "translation" else 0.0
    scale = rng.uniform(0.6, 1.6) if transform_type in ("similarity", "affine") else 1.0
    c, s = np.cos(rot), np.sin(rot)
    lin = scale * np.array([[c, -s], [s, c]])
    if transform_type == "affine":
        lin = lin @ np.array([[rng.uniform(0.85, 1.15), rng.uniform(-0.1, 0.1)],
                              [0.0, rng.uniform(0.85, 1.15)]])
    if mirrored and transform_type != "translation":
        lin = lin @ np.diag([1.0, -1.0])
    m = np.eye(3)
    m[:2, :2] = lin
    # Keep the frame centre inside the target frame: the fields overlap.
    centre = np.array([frame / 2, frame / 2])
    m[:2, 2] = centre - lin @ centre + rng.uniform(-150, 150, 2)
    return m


def write_sequence(folder, n_frames, seed, shape=(96, 96)):
    """
    Write a simulated sequence (50 stars, sky noise 5) as FITS files ``f0.fits``... in ``folder``.

    Returns the paths, the first frame (the reference) first.
    """
    from astropy.nddata import CCDData

    from astroalign_nd.io import write_ccddata
    from astroalign_nd.simulate import simulate_sequence

    seq = simulate_sequence(shape, n_frames=n_frames, n_stars=50, noise_sigma=5.0, seed=seed)
    paths = []
    for k, frame in enumerate(seq.frames):
        path = str(folder / f"f{k}.fits")
        write_ccddata(CCDData(np.asarray(frame.data), unit="adu"), path)
        paths.append(path)
    return paths
