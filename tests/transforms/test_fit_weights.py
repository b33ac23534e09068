"""The final fit's per-star weights are checked against the residuals' scatter."""

import numpy as np
import pytest

from astroalign_nd.matching.verify import _final_fit
from astroalign_nd.transforms import AffineTransform, SimilarityTransform, apply_matrix, \
    checked_weights, fit_transform

TRUTH = SimilarityTransform(scale=1.02, rotation=33.0, translation_x=40.0, translation_y=-25.0)
CORNERS = np.array([[0.0, 0.0], [1024.0, 0.0], [0.0, 1024.0], [1024.0, 1024.0]])


def corner_error(matrix):
    return float(np.max(np.hypot(*(apply_matrix(matrix, CORNERS)
                                   - apply_matrix(TRUTH.matrix, CORNERS)).T)))


def sparse_pairs(seed, bright_error):
    """
    24 pairs over a 1024 px frame: 20 faint stars (0.25 px, as claimed) and 4
    bright ones near the centre claiming 0.01 px, whose real per-axis error
    is ``bright_error``.  Returns ``(src, dst, claimed variances)``.
    """
    rng = np.random.default_rng(seed)
    src = np.vstack([rng.uniform(0, 1024, (20, 2)), rng.uniform(400, 624, (4, 2))])
    sigma = np.r_[np.full(20, 0.25), np.full(4, bright_error)]
    dst = apply_matrix(TRUTH.matrix, src) + rng.normal(0, 1, (24, 2)) * sigma[:, None]
    claimed = np.r_[np.full(20, 0.25), np.full(4, 0.01)] ** 2
    return src, dst, claimed


def errors(bright_error, fit, n_seeds=30):
    return np.array([corner_error(fit(*sparse_pairs(seed, bright_error)))
                     for seed in range(n_seeds)])


def fit_claimed(src, dst, var):
    return fit_transform(src, dst, weights=1.0 / var, parity=1)[0].matrix


def fit_unweighted(src, dst, var):
    return fit_transform(src, dst, parity=1)[0].matrix


def fit_final(src, dst, var):
    """The search's final refit of these pairs, from their claimed variances."""
    n = len(src)
    out = _final_fit((np.arange(n), np.arange(n), var, 2.0), SimilarityTransform, 1, src, dst)
    return out[0].matrix


def summary(e):
    return np.median(e), np.percentile(e, 90)


def test_wrong_errors_no_worse_than_unweighted():
    # The bright stars' errors are 15 times what they claim: weighting by
    # the claims is clearly worse than no weights at all ...
    claimed = summary(errors(0.15, fit_claimed))
    unweighted = summary(errors(0.15, fit_unweighted))
    assert claimed[0] > 1.3 * unweighted[0]
    # ... and the search's final fit, with its weights checked, is not.
    ours = summary(errors(0.15, fit_final))
    assert ours[0] <= unweighted[0] * 1.02 + 0.005, (ours, unweighted)
    assert ours[1] <= unweighted[1] * 1.02 + 0.005, (ours, unweighted)


def test_honest_errors_keep_their_weight():
    src, dst, var = sparse_pairs(0, 0.01)
    w = checked_weights(src, dst, 1.0 / var)
    assert w[-1] / w[0] > 100  # bright over faint: the claims hold
    ours = summary(errors(0.01, fit_final))
    unweighted = summary(errors(0.01, fit_unweighted))
    claimed = summary(errors(0.01, fit_claimed))
    assert ours[0] < 0.6 * unweighted[0] and ours[1] < 0.7 * unweighted[1]
    # (The check leans towards equal weights: it keeps most of the gain.)
    assert ours[0] <= 1.3 * claimed[0]


def test_scale_and_zero_weights():
    # Weights come back as inverse variances scaled to the scatter; a pair
    # left out (weight 0) stays out; the caller's array is not modified.
    rng = np.random.default_rng(5)
    src = rng.uniform(0, 500, (30, 2))
    dst = apply_matrix(TRUTH.matrix, src) + rng.normal(0, 0.3, (30, 2))
    given = np.full(30, 1.0 / 0.01**2)
    given[3] = 0.0
    before = given.copy()
    w = checked_weights(src, dst, given, "similarity", parity=1)
    assert np.array_equal(given, before)
    assert w[3] == 0.0
    assert np.allclose(w[w > 0], w[0])
    assert 0.5 < 1.0 / np.sqrt(w[0]) / 0.3 < 1.5  # per-axis sigma from the scatter


def test_too_few_pairs_and_bad_input():
    src = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [80.0, 90.0]])
    dst = src + 1.0
    w = np.array([1.0, 2.0, 3.0, 4.0])
    assert np.array_equal(checked_weights(src, dst, w), w)  # too few to judge
    with pytest.raises(ValueError, match="weights"):
        checked_weights(src, dst, [1.0, -1.0, 1.0, 1.0])


@pytest.mark.parametrize("name, parity", [("similarity", 1), ("similarity", -1),
                                          ("affine", 1), ("euclidean", 1),
                                          ("translation", 1)])
def test_leave_one_out_fits_are_the_single_fits(name, parity):
    # The jackknife's stacked leave-one-out fits give each fit's own matrix,
    # bit for bit, and a left-out wrong pair shows only in its own fit.
    from astroalign_nd.transforms.registry import transform_class
    cls = transform_class(name)
    rng = np.random.default_rng(7)
    src = rng.uniform(0, 1024, (12, 2))
    flip = np.diag([1.0, float(parity), 1.0])
    truth = TRUTH.matrix @ flip if cls.n_dof > 3 else np.eye(3) + [[0, 0, 5], [0, 0, -3], [0, 0, 0]]
    dst = apply_matrix(truth, src) + rng.normal(0, 0.05, (12, 2))
    dst[4] += 30.0  # a wrong pair
    w = rng.uniform(1.0, 50.0, 12)
    mats = cls._leave_one_out(src, dst, w, parity)
    assert mats.shape == (12, 3, 3)
    for i in range(12):
        keep = np.arange(12) != i
        single, _ = cls.fit_matrix(src[keep], dst[keep], w[keep], parity)
        assert np.array_equal(mats[i], single)
    # (The euclidean model cannot take the truth's 1.02 scale: no truth to compare.)
    if name != "euclidean":
        err = [float(np.max(np.hypot(*(apply_matrix(m, CORNERS)
                                       - apply_matrix(truth, CORNERS)).T))) for m in mats]
        assert err[4] < 0.5 < min(err[:4] + err[5:])


def test_direct_least_squares_is_numpys():
    # The fits' direct call of NumPy's least-squares kernel: its numbers bit for
    # bit, a rank-deficient design included, and its errors on bad input.
    from astroalign_nd.transforms.linear import _lstsq
    rng = np.random.default_rng(5)
    for shape in [(8, 4), (40, 6), (3, 3), (2, 4)]:
        a, b = rng.normal(size=shape), rng.normal(size=shape[0])
        assert np.array_equal(_lstsq(a, b), np.linalg.lstsq(a, b, rcond=None)[0])
    a = rng.normal(size=(10, 4))
    a[:, 3] = a[:, 0]  # rank 3
    b = rng.normal(size=10)
    assert np.array_equal(_lstsq(a, b), np.linalg.lstsq(a, b, rcond=None)[0])
    ints = np.arange(12).reshape(6, 2)  # not float: NumPy's own call
    assert np.array_equal(_lstsq(ints, np.arange(6)),
                          np.linalg.lstsq(ints, np.arange(6), rcond=None)[0])
    a[0, 0] = np.nan
    with pytest.raises(np.linalg.LinAlgError):
        _lstsq(a, b)


def test_leave_one_out_without_numpys_kernel(monkeypatch):
    # A NumPy without the private least-squares kernel: the fits one at a time,
    # the same matrices.
    from astroalign_nd.transforms import linear
    rng = np.random.default_rng(8)
    src = rng.uniform(0, 1024, (10, 2))
    dst = apply_matrix(TRUTH.matrix, src) + rng.normal(0, 0.05, (10, 2))
    w = rng.uniform(1.0, 50.0, 10)
    stacked = linear.SimilarityTransform._leave_one_out(src, dst, w, 1)
    monkeypatch.setattr(linear, "_LSTSQ", None)
    alone = linear.SimilarityTransform._leave_one_out(src, dst, w, 1)
    assert np.array_equal(stacked, alone)


@pytest.mark.parametrize("transform_type, parity", [("similarity", 1), ("similarity", -1),
                                                    ("affine", None)])
def test_given_fit_gives_the_same_weights(transform_type, parity):
    # The matching passes its last fit of the pairs: the weights are those of
    # checked_weights' own fit, and a fit the pairs do not support is still refused.
    src, dst, var = sparse_pairs(3, 0.15)
    if parity == -1:
        dst = dst * [1.0, -1.0]
    cls = SimilarityTransform if transform_type == "similarity" else AffineTransform
    fit = cls.fit_matrix(src, dst, 1.0 / var, parity or 1)
    own = checked_weights(src, dst, 1.0 / var, transform_type, parity=parity)
    given = checked_weights(src, dst, 1.0 / var, transform_type, parity=parity, fit=fit)
    assert np.array_equal(own, given)
    assert own[-1] / own[0] < 20.0  # the bright stars' claims were not borne out
    line = np.column_stack([np.arange(24.0), np.zeros(24)])
    line_fit = cls.fit_matrix(line, line, np.ones(24), parity or 1)
    with pytest.raises(ValueError, match="coincide|collinear"):
        checked_weights(line[:1].repeat(24, axis=0), line, np.ones(24), transform_type,
                        parity=parity, fit=line_fit)


@pytest.mark.parametrize("fit", [(np.eye(3),), "abc", (np.eye(2), np.zeros((40, 4))),
                                 (np.eye(3), np.zeros((39, 4)))])
def test_checked_weights_bad_fit_is_refused_clearly(fit):
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 100, (20, 2))
    with pytest.raises(ValueError, match="fit must be"):
        checked_weights(src, src + 1.0, np.ones(20), fit=fit)
