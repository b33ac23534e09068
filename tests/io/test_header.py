# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Tests of astroalign_nd.io.header (transforms in FITS headers)."""

import warnings

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.modeling import models
from astropy.utils.exceptions import AstropyUserWarning
from numpy.testing import assert_allclose, assert_array_equal

from astroalign_nd.io import transform_from_header, transform_to_header
from astroalign_nd.io.header import _read_matrix
from astroalign_nd.transforms import (
    AffineTransform,
    EuclideanTransform,
    SimilarityTransform,
    TranslationTransform,
)

from _helpers import (SAMPLE_XS, SAMPLE_YS, assert_header_refused, edit_cards,
                      sample_linear_transforms)

XS, YS = SAMPLE_XS, SAMPLE_YS
# The similarity's translation needs an exponent in a FITS card; several other
# matrix elements need all 17 significant digits: neither fits a 20-character float card.
TRANSFORMS = sample_linear_transforms(similarity_translation_y=-1.2345e-7)
TYPE_NAMES = {
    TranslationTransform: "translation",
    EuclideanTransform: "euclidean",
    SimilarityTransform: "similarity",
    AffineTransform: "affine",
}


def _assert_same_matrix(result, model):
    """
    The header stores the matrix exactly; translation and affine models take it
    as their parameters, while euclidean and similarity models recompute
    (scale, rotation) from it, which may move the last bit.
    """
    if isinstance(model, (TranslationTransform, AffineTransform)):
        assert_array_equal(result.matrix, model.matrix)
    else:
        assert_allclose(result.matrix, model.matrix, rtol=4e-16,
                        atol=4e-16 * np.abs(model.matrix).max())


def _assert_same_evaluation(model, other):
    assert_allclose(np.array(other(XS, YS)), np.array(model(XS, YS)), rtol=0.0, atol=1e-9)


@pytest.mark.parametrize("key", list(TRANSFORMS))
def test_roundtrip(key):
    model = TRANSFORMS[key]
    header = transform_to_header(model)
    assert isinstance(header, fits.Header)
    assert header["AATTYPE"] == TYPE_NAMES[type(model)]
    result = transform_from_header(header)
    assert type(result) is type(model)
    # The matrix is stored exactly.
    assert_array_equal(_read_matrix(header, "AAT"), model.matrix)
    _assert_same_matrix(result, model)
    assert result.mirrored == model.mirrored
    _assert_same_evaluation(model, result)
    _assert_same_evaluation(model.inverse, result.inverse)
    if isinstance(model, (EuclideanTransform, SimilarityTransform)):
        assert result.parity.value == model.parity.value


@pytest.mark.parametrize("key", list(TRANSFORMS))
def test_roundtrip_through_fits_file(key, tmp_path):
    model = TRANSFORMS[key]
    header = fits.Header({"OBJECT": "M31", "EXPTIME": 30.0})
    path = tmp_path / "image.fits"
    fits.PrimaryHDU(data=np.zeros((4, 5), dtype=np.float32),
                    header=transform_to_header(model, header)).writeto(path)
    with fits.open(path) as hdul:
        read_header = hdul[0].header.copy()
    result = transform_from_header(read_header)
    assert type(result) is type(model)
    assert_array_equal(_read_matrix(read_header, "AAT"), model.matrix)
    _assert_same_matrix(result, model)
    _assert_same_evaluation(model, result)
    assert read_header["OBJECT"] == "M31"
    assert read_header["EXPTIME"] == 30.0


def test_header_floats_are_rounded_but_strings_are_exact():
    # astropy writes float cards in at most 20 characters, rounding the mantissa;
    # the companion string cards keep every digit.
    model = SimilarityTransform(scale=1.2345678901234567e-5, rotation=0.3 * u.rad,
                                translation_x=1e-7 / 3.0, translation_y=2.0 / 3.0)
    header = fits.Header.fromstring(transform_to_header(model).tostring())
    m = model.matrix
    lossy = [ij for ij in ("00", "01", "02", "10", "11", "12")
             if header[f"AATM{ij}"] != m[int(ij[0]), int(ij[1])]]
    assert lossy, "expected at least one float card to be rounded by astropy"
    for ij in ("00", "01", "02", "10", "11", "12"):
        assert float(header[f"AATM{ij}S"]) == m[int(ij[0]), int(ij[1])]
        assert header[f"AATM{ij}"] == pytest.approx(m[int(ij[0]), int(ij[1])], rel=1e-12)
    assert_array_equal(_read_matrix(header, "AAT"), m)
    result = transform_from_header(header)
    _assert_same_matrix(result, model)


def test_human_readable_keywords():
    model = SimilarityTransform(scale=2.0, rotation=30.0, translation_x=5.0,
                                translation_y=-6.0, parity=-1)
    header = transform_to_header(model)
    assert header["AATSCALE"] == pytest.approx(2.0)
    assert header["AATROT"] == pytest.approx(30.0)
    assert header["AATTX"] == 5.0
    assert header["AATTY"] == -6.0
    assert header["AATPAR"] == -1
    for key in ("AATTYPE", "AATM00", "AATSCALE", "AATROT", "AATTX", "AATTY", "AATPAR"):
        assert header.comments[key]
    assert "AATSHEAR" not in header

    affine = transform_to_header(TRANSFORMS["affine-mirrored"])
    for key in ("AATSCALX", "AATSCALY", "AATROT", "AATSHEAR", "AATTX", "AATTY"):
        assert key in affine
    assert affine["AATPAR"] == -1
    assert "AATSCALE" not in affine

    translation = transform_to_header(TRANSFORMS["translation"])
    assert translation["AATSCALE"] == 1.0 and translation["AATROT"] == 0.0
    assert translation["AATPAR"] == 1


def test_rotation_keyword_is_wrapped():
    model = EuclideanTransform(rotation=30.0 + 720.0, translation_x=0.0,
                               translation_y=0.0)
    header = transform_to_header(model)
    assert header["AATROT"] == pytest.approx(30.0)
    _assert_same_evaluation(model, transform_from_header(header))


def test_non_finite_transform_rejected():
    model = SimilarityTransform(scale=np.nan, rotation=0.0, translation_x=0.0,
                                translation_y=0.0)
    with pytest.raises(ValueError, match="NaN"):
        transform_to_header(model)


def test_all_keywords_fit_in_eight_characters():
    header = transform_to_header(TRANSFORMS["affine"])
    header.update(transform_to_header(TRANSFORMS["similarity"]))
    for card in header.cards:
        assert len(card.keyword) <= 8, card.keyword
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        header.tostring()
        fits.PrimaryHDU(header=header).verify("exception")


def test_input_header_not_modified():
    header = fits.Header()
    header["OBJECT"] = ("NGC 1234", "target")
    header["AATTYPE"] = "affine"  # stale keyword from an earlier run
    header["AATSHEAR"] = 3.0
    before = header.tostring()
    out = transform_to_header(TRANSFORMS["similarity"], header)
    assert header.tostring() == before
    assert out is not header
    assert out["OBJECT"] == "NGC 1234"
    assert out.comments["OBJECT"] == "target"
    # Earlier transform keywords are replaced, not duplicated or left stale.
    assert out["AATTYPE"] == "similarity"
    assert "AATSHEAR" not in out
    assert len(out.cards) == len(set(out.keys()))
    # Modifying the output does not touch the input either.
    out["OBJECT"] = "changed"
    assert header["OBJECT"] == "NGC 1234"


def test_dict_header_and_custom_prefix():
    model = TRANSFORMS["euclidean-mirrored"]
    header = transform_to_header(model, {"OBJECT": "M51"}, prefix="xf")
    assert header["XFTYPE"] == "euclidean"
    assert "AATTYPE" not in header
    result = transform_from_header(header, prefix="XF")
    _assert_same_evaluation(model, result)
    # Two transforms in one header under different prefixes.
    both = transform_to_header(TRANSFORMS["affine"], header)
    assert type(transform_from_header(both)) is AffineTransform
    assert type(transform_from_header(both, prefix="XF")) is EuclideanTransform
    # A plain dict can be read too.
    assert type(transform_from_header(dict(both))) is AffineTransform


def test_astropy_affine_models_are_stored_as_affine():
    compound = (models.Shift(1.5) & models.Shift(-2.0)) | models.Rotation2D(angle=25.0)
    header = transform_to_header(compound)
    assert header["AATTYPE"] == "affine"
    result = transform_from_header(header)
    assert type(result) is AffineTransform
    _assert_same_evaluation(compound, result)

    ours_inside = (models.Shift(1.0) & models.Shift(2.0)) | TRANSFORMS["similarity-mirrored"]
    result = transform_from_header(transform_to_header(ours_inside))
    assert type(result) is AffineTransform
    assert result.mirrored
    _assert_same_evaluation(ours_inside, result)

    astropy_affine = models.AffineTransformation2D(matrix=[[1.0, 0.2], [-0.1, 0.9]],
                                                   translation=[3.0, 4.0])
    result = transform_from_header(transform_to_header(astropy_affine))
    _assert_same_evaluation(astropy_affine, result)


def test_user_inverse_is_dropped_with_warning():
    model = SimilarityTransform(scale=1.5, rotation=0.2 * u.rad, translation_x=1.0,
                                translation_y=2.0)
    model.inverse = models.Shift(0.0) & models.Shift(0.0)
    with pytest.warns(AstropyUserWarning, match="user-assigned inverse"):
        header = transform_to_header(model)
    result = transform_from_header(header)
    assert not result.has_user_inverse
    _assert_same_evaluation(SimilarityTransform(*model.parameters).inverse, result.inverse)


def test_float_cards_alone_still_read():
    # A header written by hand (or by other software) with only the float cards.
    model = TRANSFORMS["similarity"]
    header = transform_to_header(model)
    for ij in ("00", "01", "02", "10", "11", "12"):
        del header[f"AATM{ij}S"]
    result = transform_from_header(header)
    assert type(result) is SimilarityTransform
    _assert_same_evaluation(model, result)


# -- errors --------------------------------------------------------------------


def test_non_linear_model_rejected():
    with pytest.raises(ValueError, match="linear 2-D astropy models.*ASDF"):
        transform_to_header(models.Pix2Sky_TAN())
    with pytest.raises(ValueError, match="linear 2-D astropy models.*ASDF"):
        transform_to_header(models.Shift(3.0))  # 1 input, 1 output
    with pytest.raises(ValueError, match="linear 2-D astropy models"):
        transform_to_header(models.Polynomial2D(2, c2_0=1e-3) & models.Shift(1.0))


def test_non_model_rejected():
    with pytest.raises(TypeError, match="astropy model"):
        transform_to_header(np.eye(3))


def test_model_set_rejected():
    model = TranslationTransform(translation_x=[1.0, 2.0], translation_y=[3.0, 4.0],
                                 n_models=2)
    with pytest.raises(ValueError, match="parameter sets"):
        transform_to_header(model)


@pytest.mark.parametrize("prefix", ["", "TOOLONG", "A B", "AA*"])
def test_bad_prefix(prefix):
    with pytest.raises(ValueError, match="prefix"):
        transform_to_header(TRANSFORMS["translation"], prefix=prefix)
    with pytest.raises(ValueError, match="prefix"):
        transform_from_header(fits.Header(), prefix=prefix)


def test_header_without_keywords():
    with pytest.raises(ValueError, match=r"no astroalign_nd transform keywords \(AATTYPE"):
        transform_from_header(fits.Header({"OBJECT": "M31"}))
    header = transform_to_header(TRANSFORMS["affine"])
    with pytest.raises(ValueError, match=r"no astroalign_nd transform keywords \(ZZTYPE"):
        transform_from_header(header, prefix="ZZ")


@pytest.mark.parametrize("key, change, message", [
    ("affine", edit_cards(AATTYPE="homography"), "AATTYPE must be one of"),
    ("affine", edit_cards("AATM12", "AATM12S"), "AATM12"),
    # the float card no longer agrees with the exact string card beside it
    ("similarity", edit_cards(AATM02=TRANSFORMS["similarity"].matrix[0, 2] + 1.0),
     "AATM02.*disagree"),
    ("affine", edit_cards(AATTYPE="similarity"), "not a valid SimilarityTransform"),
], ids=["unknown-type", "incomplete-matrix", "float-card-edited", "type-not-the-matrix"])
def test_edited_header_is_refused(key, change, message):
    assert_header_refused(TRANSFORMS[key], change, message)


def test_bad_header_argument():
    with pytest.raises(TypeError, match="header must be"):
        transform_to_header(TRANSFORMS["affine"], header=42)
    with pytest.raises(TypeError, match="header must be"):
        transform_from_header(42)


def test_header_without_wcs_keeps_the_rest_and_the_input():
    from astroalign_nd.io.header import header_without_wcs

    h = fits.Header({"OBJECT": "M31", "CTYPE1": "RA---TAN", "CTYPE2": "DEC--TAN",
                     "CRPIX1": 10.0, "CRPIX2": 12.0, "CRVAL1": 10.7, "CRVAL2": 41.3,
                     "CD1_1": -1e-4, "CD1_2": 0.0, "CD2_1": 0.0, "CD2_2": 1e-4,
                     "EXPTIME": 30.0})
    out = header_without_wcs(h)
    assert list(out.keys()) == ["OBJECT", "EXPTIME"]
    assert "CTYPE1" in h and len(h) == 12  # the caller's header is untouched
    # An unparsable WCS is removed by name.
    bad = fits.Header({"CTYPE1": "NOT-A-PROJ", "CRPIX1": "x", "FILTER": "R"})
    assert list(header_without_wcs(bad).keys()) == ["FILTER"]
