# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The non-linear models in FITS headers, and the source frame's TAN-SIP WCS."""

import warnings

import numpy as np
import pytest
from astropy.io import fits
from astropy.wcs import WCS

from astroalign_nd import PolynomialTransform, ProjectiveTransform, SimilarityTransform
from astroalign_nd.io import add_provenance, transform_from_header, transform_to_header
from astroalign_nd.io.sip import distorted_wcs

from _helpers import assert_header_refused, edit_cards

SHAPE = (3000, 4096)  # (ny, nx)
DOMAIN = (0.0, SHAPE[1] - 1.0, 0.0, SHAPE[0] - 1.0)


def barrel(degree=3):
    """A few pixels of barrel distortion at the corners, plus rotation, scale and shift."""
    c, s = 1.002 * np.cos(np.radians(-2.0)), 1.002 * np.sin(np.radians(-2.0))
    k = -1.2e-9
    params = dict(a11=c, a12=-s, a21=s, a22=c, translation_x=2050.0 / 3.0 + 1400.0,
                  translation_y=1510.0, A_3_0=k, A_1_2=k, B_2_1=k, B_0_3=k,
                  A_2_0=1e-7, B_1_1=-2.0e-7 / 3.0)
    if degree == 5:
        k5 = 2e-16
        params.update(A_5_0=k5, A_3_2=2 * k5, A_1_4=k5, B_4_1=k5, B_2_3=2 * k5, B_0_5=k5)
    return PolynomialTransform(degree=degree, crpix=(2047.5, 1499.5), domain=DOMAIN, **params)


MODELS = {
    "projective": ProjectiveTransform(h11=1.0012, h12=0.0153, h13=-12.0 / 7.0, h21=-0.0121,
                                      h22=0.9987, h23=30.25, h31=2.1e-6, h32=-1.3e-6 / 3.0),
    "polynomial-3": barrel(3),
    "polynomial-5": barrel(5),
    "polynomial-2": PolynomialTransform(degree=2, crpix=(0.0, 0.0), A_2_0=1e-6 / 3.0,
                                        B_0_2=2e-7, translation_x=5.5),
}


def _grid(n=41):
    gx, gy = np.meshgrid(np.linspace(0, SHAPE[1] - 1, n), np.linspace(0, SHAPE[0] - 1, n))
    return gx.ravel(), gy.ravel()


def _max_distance(a, b):
    x, y = _grid()
    xa, ya = a(x, y)
    xb, yb = b(x, y)
    return float(np.max(np.hypot(xa - xb, ya - yb)))


@pytest.mark.parametrize("key", list(MODELS))
def test_header_roundtrip_through_a_file(key, tmp_path):
    model = MODELS[key]
    header = transform_to_header(model, fits.Header({"OBJECT": "M31"}))
    for card in header.cards:
        assert len(card.keyword) <= 8, card.keyword
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fits.PrimaryHDU(np.zeros((2, 2)), header=header).writeto(tmp_path / "f.fits")
    back = transform_from_header(fits.getheader(tmp_path / "f.fits"))
    assert type(back) is type(model)
    assert _max_distance(back, model) < 1e-6  # pixels, over the frame (the figure)
    # The exact strings give the parameters bit for bit.
    np.testing.assert_array_equal(back.parameters, model.parameters)
    if isinstance(model, PolynomialTransform):
        assert back.degree == model.degree and back.crpix == model.crpix
        assert back.domain == model.domain
        if model.domain is not None:
            assert back.inverse_error == model.inverse_error
    assert header["OBJECT"] == "M31"


def test_header_float_cards_alone_are_within_1e6_px():
    model = MODELS["polynomial-5"]
    header = transform_to_header(model)
    for key in [k for k in header if k.endswith("S")]:  # the exact strings
        del header[key]
    back = transform_from_header(header)
    assert _max_distance(back, model) < 1e-6


def test_header_replaces_a_previous_transform():
    header = transform_to_header(MODELS["polynomial-5"])
    header = transform_to_header(SimilarityTransform(scale=2.0), header)
    assert not any(k.startswith(("AATA", "AATB", "AATDEG", "AATCRP", "AATDX")) for k in header)
    assert type(transform_from_header(header)) is SimilarityTransform
    header = transform_to_header(MODELS["polynomial-2"], transform_to_header(MODELS["projective"]))
    assert "AATM20" not in header
    assert type(transform_from_header(header)) is PolynomialTransform


@pytest.mark.parametrize("model_key, change, message", [
    ("polynomial-3", edit_cards(AATDEG=7), "AATDEG"),
    ("polynomial-3", edit_cards(AATDEG=2), "beyond AATDEG"),
    ("polynomial-3", edit_cards("AATB03", "AATB03S"), "AATB03"),
    ("polynomial-3", edit_cards("AATDYMAX"), "all four"),
    ("polynomial-3", edit_cards(AATA30=1.0), "AATA30.*disagree"),
    ("polynomial-3", edit_cards(AATM00=0.0, AATM00S="0.0", AATM01=0.0, AATM01S="0.0"), "singular"),
    ("projective", edit_cards("AATM21", "AATM21S"), "AATM21"),
    ("projective", edit_cards(AATM20S="nan"), "finite"),
])
def test_damaged_header(model_key, change, message):
    assert_header_refused(MODELS[model_key], change, message)


def test_add_provenance_accepts_the_new_models():
    quality = {"n_matches": 300, "rms": 0.04, "log10_false_alarm": -200.0}
    for key, model in MODELS.items():
        out = add_provenance(fits.Header(), model, quality=quality, source_name="a.fits",
                             target_name="b.fits")
        assert out["AATNMAT"] == 300
        history = " ".join(str(h) for h in out["HISTORY"])
        assert type(model).__name__ in history
        assert _max_distance(transform_from_header(out), model) < 1e-6
    assert "degree=5" in " ".join(str(h) for h in add_provenance(
        fits.Header(), MODELS["polynomial-5"])["HISTORY"])


# -- the source frame's TAN-SIP WCS ---------------------------------------------------

def _target_wcs(kind="cd"):
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [83.63, 22.01]
    w.wcs.crpix = [2100.5, 1450.25]
    scale = 1.5 / 3600.0  # a wide field: 1.5 arcsec/px, 1.7 x 1.25 degrees
    if kind == "cd":
        a = np.radians(25.0)
        w.wcs.cd = scale * np.array([[-np.cos(a), np.sin(a)], [np.sin(a), np.cos(a)]])
    else:
        w.wcs.cdelt = [-scale, scale]
        w.wcs.pc = [[0.99, 0.05], [-0.05, 0.99]]
    return w


@pytest.mark.parametrize("key", ["polynomial-3", "polynomial-5", "polynomial-2"])
@pytest.mark.parametrize("kind", ["cd", "pc"])
def test_distorted_wcs_agrees_with_the_model_over_the_frame(key, kind):
    model = MODELS[key]
    target = _target_wcs(kind)
    source = distorted_wcs(model, target, SHAPE)
    assert source.sip is not None and source.wcs.ctype[0].endswith("-SIP")
    assert source.pixel_shape == (SHAPE[1], SHAPE[0])
    x, y = _grid()
    # pixel -> sky through the SIP WCS, back to target pixels: the model's positions.
    xt, yt = target.world_to_pixel(source.pixel_to_world(x, y))
    mx, my = model(x, y)
    assert np.max(np.hypot(xt - mx, yt - my)) < 0.1  # target pixels (the figure)
    assert np.max(np.hypot(xt - mx, yt - my)) < 1e-6  # it is in fact exact
    # sky -> pixel (astropy iterates on the forward terms), and the fitted AP/BP terms.
    xs, ys = source.world_to_pixel(target.pixel_to_world(mx, my))
    assert np.max(np.hypot(xs - x, ys - y)) < 1e-4
    u, v = source.sip.foc2pix(source.sip.pix2foc(np.column_stack([x, y]), 0), 0).T
    assert np.max(np.hypot(u - x, v - y)) < 0.01
    # The WCS survives a FITS header.
    again = WCS(source.to_header(relax=True))
    xt2, yt2 = target.world_to_pixel(again.pixel_to_world(x, y))
    assert np.max(np.hypot(xt2 - mx, yt2 - my)) < 1e-6


def test_distorted_wcs_a_linear_wcs_would_be_pixels_off():
    """The SIP terms matter: without them the corners are off by the distortion."""
    model = MODELS["polynomial-3"]
    target = _target_wcs()
    source = distorted_wcs(model, target, SHAPE)
    xy = np.column_stack(_grid())
    # wcs_pix2world leaves the SIP terms out.
    linear = target.wcs_world2pix(source.wcs_pix2world(xy, 0), 0)
    full = target.wcs_world2pix(source.all_pix2world(xy, 0), 0)
    truth = np.column_stack(model(*xy.T))
    assert np.max(np.hypot(*(linear - truth).T)) > 1.0
    assert np.max(np.hypot(*(full - truth).T)) < 1e-6


def test_distorted_wcs_bad_input():
    target = _target_wcs()
    with pytest.raises(TypeError, match="PolynomialTransform"):
        distorted_wcs(SimilarityTransform(), target, SHAPE)
    with pytest.raises(TypeError, match="astropy.wcs.WCS"):
        distorted_wcs(MODELS["polynomial-3"], target.to_header(), SHAPE)
    with pytest.raises(ValueError, match="celestial"):
        linear = WCS(naxis=2)
        distorted_wcs(MODELS["polynomial-3"], linear, SHAPE)
    sip = distorted_wcs(MODELS["polynomial-3"], target, SHAPE)
    with pytest.raises(ValueError, match="already has distortion"):
        distorted_wcs(MODELS["polynomial-3"], sip, SHAPE)
    for shape in ((0, 10), (10,), "big"):
        with pytest.raises(ValueError, match="shape"):
            distorted_wcs(MODELS["polynomial-3"], target, shape)
    with pytest.raises(ValueError, match="inverse_degree"):
        distorted_wcs(MODELS["polynomial-3"], target, SHAPE, inverse_degree=12)
