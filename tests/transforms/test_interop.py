# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Interoperability of the transforms with scikit-image, astropy and plain
matrices (astroalign_nd.transforms: as_matrix, from_matrix, to/from_skimage,
to/from_astropy_affine).
"""

import numpy as np
import pytest
from astropy import units as u
from astropy.modeling import models
from numpy.testing import assert_allclose, assert_array_equal
from skimage import transform as sktf

from astroalign_nd.transforms import (
    AffineTransform,
    EuclideanTransform,
    SimilarityTransform,
    TranslationTransform,
    as_matrix,
    from_astropy_affine,
    from_matrix,
    from_skimage,
    to_astropy_affine,
    to_skimage,
)

from _helpers import SAMPLE_XS, SAMPLE_YS, sample_linear_transforms

XS, YS = SAMPLE_XS, SAMPLE_YS
POINTS = np.column_stack([XS, YS])
TRANSFORMS = sample_linear_transforms()
KEYS = list(TRANSFORMS)

# The class scikit-image uses for each: its Euclidean/Similarity classes
# cannot hold a reflection, so mirrored transforms go to AffineTransform.
SKIMAGE_CLASS = {
    "translation": sktf.EuclideanTransform,
    "euclidean": sktf.EuclideanTransform,
    "euclidean-mirrored": sktf.AffineTransform,
    "similarity": sktf.SimilarityTransform,
    "similarity-mirrored": sktf.AffineTransform,
    "affine": sktf.AffineTransform,
    "affine-mirrored": sktf.AffineTransform,
}


def _evaluate(model):
    """(N, 2) output of an astropy model or a scikit-image transform."""
    if hasattr(model, "n_inputs"):
        return np.column_stack(model(XS, YS))
    return model(POINTS)


def _assert_same_evaluation(model, other, atol=1e-9):
    assert_allclose(_evaluate(other), _evaluate(model), rtol=0.0, atol=atol)


def _assert_converts_back(model, convert, foreign):
    """``convert(foreign)``, with the type guessed or given, is ``model`` again."""
    for back in (convert(foreign), convert(foreign, type(model))):
        assert type(back) is type(model)
        _assert_same_evaluation(model, back)
        assert back.mirrored == model.mirrored


def _expected(model):
    """Direct evaluation of the documented formula, independent of the model code."""
    m = model.matrix
    return POINTS @ m[:2, :2].T + m[:2, 2]


# -- the models themselves -------------------------------------------------------


def test_formulas():
    t = TRANSFORMS
    tx, ty = 12.345678901234567, -7.0 / 3.0
    assert_allclose(_evaluate(t["translation"]), POINTS + [tx, ty], rtol=0, atol=1e-12)
    s, r, p = 0.5, 3.0, -1
    rot = np.array([[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]])
    expected = s * POINTS @ (rot @ np.diag([1.0, p])).T + [-20.0, 5.5]
    assert_allclose(_evaluate(t["similarity-mirrored"]), expected, rtol=0, atol=1e-9)
    for model in TRANSFORMS.values():
        assert_allclose(_evaluate(model), _expected(model), rtol=0, atol=1e-9)


@pytest.mark.parametrize("key", KEYS)
def test_mirrored_flag_and_inverse(key):
    model = TRANSFORMS[key]
    assert model.mirrored == key.endswith("mirrored")
    assert np.linalg.det(model.matrix[:2, :2]) * (-1 if model.mirrored else 1) > 0
    inverse = model.inverse
    assert type(inverse) is type(model)
    assert inverse.mirrored == model.mirrored
    back = np.column_stack(inverse(*model(XS, YS)))
    assert_allclose(back, POINTS, rtol=0, atol=1e-9)


def test_matrix_is_exact_with_large_translation():
    # The matrix must not be computed by differencing A e + t and t, which
    # loses the low bits of A when the shift is much larger than A.
    model = SimilarityTransform(scale=1.2345678901234567e-5, rotation=0.3 * u.rad,
                                translation_x=1e4 / 3.0, translation_y=-2e4 / 7.0)
    m = model.matrix
    c, s = 1.2345678901234567e-5 * np.cos(0.3), 1.2345678901234567e-5 * np.sin(0.3)
    assert_array_equal(m[:2, :2], [[c, -s], [s, c]])
    assert_array_equal(m[:2, 2], [1e4 / 3.0, -2e4 / 7.0])


# -- as_matrix / from_matrix -----------------------------------------------------


@pytest.mark.parametrize("key", KEYS)
def test_as_matrix_and_from_matrix(key):
    model = TRANSFORMS[key]
    m = as_matrix(model)
    assert m.shape == (3, 3)
    assert_array_equal(m[2], [0.0, 0.0, 1.0])
    assert_array_equal(m, model.matrix)
    assert_array_equal(model.params, m)
    assert_array_equal(as_matrix(m[:2]), m)
    # Same class requested: same class back.
    same = type(model).from_matrix(m)
    assert type(same) is type(model)
    _assert_same_evaluation(model, same)
    assert type(from_matrix(m, type(model))) is type(model)
    assert type(from_matrix(m[:2], key.split("-")[0])) is type(model)
    # Automatic choice: the simplest class that represents it, here the same.
    auto = from_matrix(m)
    assert type(auto) is type(model)
    _assert_same_evaluation(model, auto)
    if isinstance(model, (EuclideanTransform, SimilarityTransform)):
        assert auto.parity.value == model.parity.value
    # Any class can be widened to affine.
    wide = AffineTransform.from_matrix(m)
    _assert_same_evaluation(model, wide)
    assert wide.mirrored == model.mirrored


@pytest.mark.parametrize(
    ("matrix", "expected"),
    [
        (np.eye(3), TranslationTransform),
        (np.diag([1.0, -1.0, 1.0]), EuclideanTransform),
        (np.diag([-1.0, 1.0, 1.0]), EuclideanTransform),
        (np.diag([2.0, -2.0, 1.0]), SimilarityTransform),
        (np.diag([2.0, 3.0, 1.0]), AffineTransform),
    ],
)
def test_from_matrix_picks_simplest_class(matrix, expected):
    model = from_matrix(matrix)
    assert type(model) is expected
    assert_allclose(model.matrix, matrix, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    ("model", "not_a"),
    [
        (SimilarityTransform(scale=1.000004, rotation=0.2 * u.rad, translation_x=5.0,
                             translation_y=3.0), (TranslationTransform, EuclideanTransform)),
        (AffineTransform(a11=1.000004, a12=0.0, a21=0.0, a22=1.0, translation_x=5.0,
                         translation_y=3.0),
         (TranslationTransform, EuclideanTransform, SimilarityTransform)),
    ],
    ids=["scale-1e-6", "anisotropic-1e-6"],
)
def test_from_matrix_does_not_drop_small_scale_or_shear(model, not_a):
    # A scale difference of 4e-6 is 8e-3 px at x = 2000: it must not be
    # rounded away by a relative tolerance when choosing the class.
    auto = from_matrix(model.matrix)
    assert not isinstance(auto, not_a)
    _assert_same_evaluation(model, auto)
    for cls in not_a:
        with pytest.raises(ValueError, match="instead of"):
            cls.from_matrix(model.matrix)


def test_from_matrix_errors():
    with pytest.raises(ValueError, match="shear or anisotropic"):
        SimilarityTransform.from_matrix(TRANSFORMS["affine"].matrix)
    with pytest.raises(ValueError, match="scale or shear"):
        EuclideanTransform.from_matrix(TRANSFORMS["similarity"].matrix)
    with pytest.raises(ValueError, match="rotation, scale or shear"):
        TranslationTransform.from_matrix(TRANSFORMS["euclidean"].matrix)
    projective = np.eye(3)
    projective[2, 0] = 1e-3
    with pytest.raises(ValueError, match="projective"):
        from_matrix(projective)
    with pytest.raises(ValueError, match="shape"):
        AffineTransform.from_matrix(np.eye(2))
    with pytest.raises(ValueError, match="NaN"):
        AffineTransform.from_matrix(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="transform_type"):
        from_matrix(np.eye(3), "homography")
    assert type(from_matrix(projective, "projective")).__name__ == "ProjectiveTransform"
    with pytest.raises(ValueError, match="PolynomialTransform"):
        from_matrix(np.eye(3), "polynomial")


def test_as_matrix_of_astropy_models():
    compound = ((models.Shift(1.5) & models.Shift(-2.0)) | models.Rotation2D(angle=25.0)
                | (models.Scale(2.0) & models.Scale(2.0)))
    m = as_matrix(compound)
    model = from_matrix(m)
    assert type(model) is SimilarityTransform
    _assert_same_evaluation(compound, model)

    ours_inside = (models.Shift(1.0) & models.Shift(2.0)) | TRANSFORMS["similarity-mirrored"]
    model = from_matrix(as_matrix(ours_inside))
    assert model.mirrored
    _assert_same_evaluation(ours_inside, model)

    with pytest.raises(ValueError, match="not an affine transform"):
        as_matrix(models.Pix2Sky_TAN())
    with pytest.raises(TypeError, match="2 inputs and 2 outputs"):
        as_matrix(models.Shift(1.0))
    with pytest.raises(TypeError, match="3x3 matrix"):
        as_matrix(np.eye(4))


# -- scikit-image ----------------------------------------------------------------


@pytest.mark.parametrize("key", KEYS)
def test_to_and_from_skimage(key):
    model = TRANSFORMS[key]
    sk = to_skimage(model)
    assert type(sk) is SKIMAGE_CLASS[key]
    assert_allclose(sk.params, model.matrix, rtol=0, atol=1e-15)
    _assert_same_evaluation(model, sk)
    # The skimage inverse agrees with ours.
    assert_allclose(sk.inverse(POINTS), _evaluate(model.inverse), rtol=0, atol=1e-9)

    _assert_converts_back(model, from_skimage, sk)


def test_skimage_attributes_match():
    # scale, rotation and translation mean the same thing on both sides.
    for key in ("euclidean", "similarity", "affine"):
        model = TRANSFORMS[key]
        sk = to_skimage(model)
        assert_allclose(sk.translation, model.translation, rtol=0, atol=1e-12)
        assert_allclose(sk.rotation, np.deg2rad(model.rotation_deg), rtol=0,
                        atol=1e-12)
        if hasattr(sk, "scale"):  # scikit-image's EuclideanTransform has none
            assert_allclose(sk.scale, np.asarray(model.scale, dtype=float), rtol=0,
                            atol=1e-12)
        if hasattr(sk, "shear"):
            assert_allclose(sk.shear, np.deg2rad(model.shear), rtol=0, atol=1e-12)


def test_affine_scale_shear_rotation_like_skimage():
    # Built from scikit-image's (scale, rotation, shear) parameters, the model
    # reports the same values back.
    sk = sktf.AffineTransform(scale=(1.3, 0.7), rotation=0.4, shear=0.25,
                              translation=(5.0, -6.0))
    model = from_skimage(sk, "affine")
    assert_allclose(model.scale, [1.3, 0.7], rtol=0, atol=1e-12)
    assert model.rotation == pytest.approx(np.degrees(0.4), abs=1e-10)
    assert model.shear == pytest.approx(np.degrees(0.25), abs=1e-10)
    assert_allclose(model.translation, [5.0, -6.0], rtol=0, atol=1e-12)


def test_from_skimage_native_transforms():
    sk = sktf.SimilarityTransform(scale=1.7, rotation=-0.4, translation=(30.0, -12.0))
    model = from_skimage(sk)
    assert type(model) is SimilarityTransform
    assert model.scale.value == pytest.approx(1.7)
    assert model.rotation.value == pytest.approx(np.degrees(-0.4))
    _assert_same_evaluation(sk, model)

    sk = sktf.EuclideanTransform(rotation=2.5, translation=(3.0, 4.0))
    model = from_skimage(sk)
    assert type(model) is EuclideanTransform
    _assert_same_evaluation(sk, model)

    # A mirrored affine from scikit-image becomes a mirrored similarity when it is one.
    flip = sktf.AffineTransform(matrix=np.array([[0.0, 2.0, 1.0], [2.0, 0.0, 5.0],
                                                 [0.0, 0.0, 1.0]]))
    model = from_skimage(flip)
    assert type(model) is SimilarityTransform
    assert model.parity.value == -1
    _assert_same_evaluation(flip, model)

    sk = sktf.AffineTransform(scale=(1.1, 0.9), rotation=0.3, shear=0.05,
                              translation=(2.0, 3.0))
    model = from_skimage(sk)
    assert type(model) is AffineTransform
    _assert_same_evaluation(sk, model)
    with pytest.raises(ValueError, match="shear or anisotropic"):
        from_skimage(sk, "similarity")

    projective = sktf.ProjectiveTransform(matrix=np.array([[1.0, 0.0, 0.0],
                                                           [0.0, 1.0, 0.0],
                                                           [1e-3, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="projective"):
        from_skimage(projective)


# -- astropy AffineTransformation2D ---------------------------------------------


@pytest.mark.parametrize("key", KEYS)
def test_to_and_from_astropy_affine(key):
    model = TRANSFORMS[key]
    affine = to_astropy_affine(model)
    assert isinstance(affine, models.AffineTransformation2D)
    assert_array_equal(affine.matrix.value, model.matrix[:2, :2])
    assert_array_equal(affine.translation.value, model.matrix[:2, 2])
    _assert_same_evaluation(model, affine)
    _assert_same_evaluation(model.inverse, affine.inverse)

    _assert_converts_back(model, from_astropy_affine, affine)


def test_from_astropy_affine_native():
    affine = models.AffineTransformation2D(matrix=[[0.0, -1.0], [1.0, 0.0]],
                                           translation=[10.0, 20.0])
    model = from_astropy_affine(affine)
    assert type(model) is EuclideanTransform
    assert model.rotation.value == pytest.approx(90.0)
    _assert_same_evaluation(affine, model)
    with pytest.raises(ValueError, match="rotation, scale or shear"):
        from_astropy_affine(affine, "translation")


@pytest.mark.parametrize("key", KEYS)
def test_compose_with_astropy_models(key):
    model = TRANSFORMS[key]
    compound = (models.Shift(-1.0) & models.Shift(2.0)) | model | models.Rotation2D(angle=15.0)
    m = as_matrix(compound)
    rot = np.radians(15.0)
    r = np.eye(3)
    r[:2, :2] = [[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]]
    shift = np.eye(3)
    shift[:2, 2] = [-1.0, 2.0]
    assert_allclose(m, r @ model.matrix @ shift, rtol=0, atol=1e-9)
    _assert_same_evaluation(compound, from_matrix(m))
