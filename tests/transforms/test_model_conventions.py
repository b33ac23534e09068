# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The models follow astropy.modeling: degrees, Quantity, validated parity, weighted fits."""

import numpy as np
import pytest
from astropy import units as u
from astropy.modeling.models import Rotation2D, Scale

from astroalign_nd import EuclideanTransform, SimilarityTransform, TranslationTransform
from astroalign_nd.transforms import AffineTransform, fit_transform


@pytest.mark.parametrize("angle", [30.0, -117.5, 271.0])
def test_rotation_in_degrees_like_rotation2d(angle):
    x = np.array([0.0, 1.0, 10.0, -3.5])
    y = np.array([0.0, 2.0, -4.0, 7.25])
    for model in (EuclideanTransform(rotation=angle), SimilarityTransform(rotation=angle)):
        np.testing.assert_allclose(model(x, y), Rotation2D(angle)(x, y), atol=1e-12)
        assert float(model.rotation.value) == angle
        assert model.rotation_deg == angle
    # a scaled rotation is Rotation2D | Scale & Scale
    scaled = Rotation2D(angle) | Scale(1.3) & Scale(1.3)
    np.testing.assert_allclose(SimilarityTransform(scale=1.3, rotation=angle)(x, y),
                               scaled(x, y), atol=1e-12)


def test_rotation_quantity_is_converted_to_degrees():
    t = SimilarityTransform(rotation=np.pi / 3 * u.rad, translation_x=2.0)
    assert t.rotation.unit is None
    assert t.rotation.value == pytest.approx(60.0, abs=1e-12)
    assert EuclideanTransform(rotation=90 * u.deg).rotation_deg == 90.0
    assert EuclideanTransform(rotation=5400 * u.arcmin).rotation_deg == pytest.approx(90.0)
    t.rotation = 0.5 * u.deg
    assert t.rotation.value == 0.5
    t.rotation = 45.0
    assert t.rotation.value == 45.0
    with pytest.raises(u.UnitsError, match="angle"):
        SimilarityTransform(rotation=3 * u.m)
    # a round trip through the matrix keeps degrees
    back = SimilarityTransform.from_matrix(t.matrix)
    assert back.rotation.value == pytest.approx(45.0, abs=1e-12)
    assert t.inverse.rotation.value == pytest.approx(-45.0, abs=1e-12)


@pytest.mark.parametrize("bad", [0, 0.5, 2, -3, np.nan])
def test_parity_is_validated(bad):
    with pytest.raises(ValueError, match=r"parity must be \+1 .* or -1"):
        SimilarityTransform(parity=bad)
    with pytest.raises(ValueError, match="parity"):
        EuclideanTransform(rotation=10.0, parity=bad)
    t = SimilarityTransform()
    with pytest.raises(ValueError, match="parity"):
        t.parity = bad
    assert t.parity.value == 1.0  # unchanged
    src = np.random.default_rng(1).uniform(0, 100, (10, 2))
    for cls in (SimilarityTransform, EuclideanTransform, AffineTransform):
        with pytest.raises(ValueError, match="parity"):
            cls.from_points(src, src, parity=bad)


def test_parity_minus_one_and_plus_one_accepted():
    assert SimilarityTransform(parity=-1).mirrored
    assert not SimilarityTransform(parity=1.0).mirrored
    t = SimilarityTransform()
    t.parity = -1
    assert t.mirrored


def test_from_points_weights_refit_own_catalog():
    rng = np.random.default_rng(7)
    truth = SimilarityTransform(scale=0.98, rotation=-12.0, translation_x=40.0,
                                translation_y=-7.0)
    src = rng.uniform(0, 1000, (60, 2))
    sigma = rng.uniform(0.05, 2.0, 60)  # very different position errors
    dst = np.column_stack(truth(*src.T)) + rng.normal(0, 1, (60, 2)) * sigma[:, None]
    dst[:5] += 40.0  # five bad matches
    w = 1.0 / sigma**2
    w[:5] = 0.0

    def corner_error(model):
        c = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0], [1000.0, 1000.0]])
        return np.max(np.hypot(*(np.subtract(model(*c.T), truth(*c.T)))))

    weighted = SimilarityTransform.from_points(src, dst, weights=w)
    unweighted = SimilarityTransform.from_points(src[5:], dst[5:])
    assert corner_error(weighted) < 0.5
    # inverse-variance weights beat equal weights on heteroscedastic errors
    # (here 0.22 px against 0.45 px)
    assert corner_error(weighted) < 0.75 * corner_error(unweighted)
    # zero weight is the same as leaving the pair out
    kept = SimilarityTransform.from_points(src[5:], dst[5:], weights=w[5:])
    np.testing.assert_allclose(weighted.matrix, kept.matrix, atol=1e-10)
    with pytest.raises(ValueError, match=r"shape \(60,\)"):
        SimilarityTransform.from_points(src, dst, weights=np.ones(59))
    with pytest.raises(ValueError, match="non-negative"):
        SimilarityTransform.from_points(src, dst, weights=-w)
    with pytest.raises(ValueError, match="non-zero weight"):
        SimilarityTransform.from_points(src, dst, weights=np.eye(60)[0])
    t = TranslationTransform.from_points(src[5:], dst[5:], weights=w[5:])
    assert isinstance(t, TranslationTransform)


def test_rotation_covariance_in_degrees():
    """The fitted rotation scatters as the covariance says, in degrees."""
    rng = np.random.default_rng(3)
    truth_kw = dict(rotation=25.0, translation_x=3.0, translation_y=4.0)
    src = rng.uniform(0, 200, (30, 2))
    for cls in (EuclideanTransform, SimilarityTransform):
        truth = cls(**truth_kw)
        clean = np.column_stack(truth(*src.T))
        angles, sigmas = [], []
        for _ in range(300):
            dst = clean + rng.normal(0, 0.5, clean.shape)
            model, cov, _ = fit_transform(src, dst, cls)
            k = model.param_names.index("rotation")
            angles.append(model.rotation.value)
            sigmas.append(np.sqrt(cov[k, k]))
        assert np.std(angles) == pytest.approx(np.median(sigmas), rel=0.15)
        assert np.mean(angles) == pytest.approx(25.0, abs=0.02)
