# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""A source's distortion WCS carried onto the target grid when the target has no WCS."""

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData
from astropy.wcs import WCS, DistortionLookupTable, Sip

from astroalign_nd import AstroalignWarning, SimilarityTransform, apply_transform

NY, NX = 300, 400


def _sip_wcs(inverse=False):
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN-SIP", "DEC--TAN-SIP"]
    w.wcs.crval = [150.0, 2.0]
    w.wcs.crpix = [180.0, 140.0]
    w.wcs.cd = np.array([[-1.0, 0.05], [0.03, 1.0]]) / 3600.0  # 1 arcsec pixels
    a, b = np.zeros((4, 4)), np.zeros((4, 4))
    a[2, 0], a[1, 1], a[0, 2], a[3, 0] = 2e-5, -1e-5, 3e-6, 1e-8
    b[0, 2], b[2, 1], b[1, 1] = 2e-5, -1e-8, 5e-6
    ap, bp = (-a, -b) if inverse else (None, None)  # first-order inverse: enough to compare
    w.sip = Sip(a, b, ap, bp, w.wcs.crpix)
    w.pixel_shape = (NX, NY)
    return w


TRANSFORM = SimilarityTransform(rotation=12.0, scale=1.03, translation_x=15.0,
                                translation_y=-8.0)


def _grid():
    yy, xx = np.mgrid[0:NY:20j, 0:NX:20j]
    return np.column_stack([xx.ravel(), yy.ravel()])


def _sky_error_px(w_src, w_out):
    """Largest distance on the sky (in 1-arcsec pixels) between the two over the output."""
    q = _grid()
    p = np.column_stack(TRANSFORM.inverse(q[:, 0], q[:, 1]))
    s1, s2 = w_src.all_pix2world(p, 0), w_out.all_pix2world(q, 0)
    d = np.hypot((s1[:, 0] - s2[:, 0]) * np.cos(np.radians(s1[:, 1])), s1[:, 1] - s2[:, 1])
    return float(d.max() * 3600.0)


def _aligned(w):
    src = CCDData(np.zeros((NY, NX)), unit="adu", wcs=w)
    return apply_transform(TRANSFORM, src, np.zeros((NY, NX)))


def test_sip_follows_a_linear_transform():
    w = _sip_wcs()
    out = _aligned(w)
    assert out.wcs.sip is not None and out.wcs.wcs.ctype[0].endswith("-SIP")
    assert _sky_error_px(w, out.wcs) < 0.01  # it was 1.5 px with SIP dropped


def test_sip_survives_the_fits_file(tmp_path):
    w = _sip_wcs()
    _aligned(w).write(tmp_path / "a.fits")
    back = WCS(fits.getheader(tmp_path / "a.fits"))
    assert _sky_error_px(w, back) < 0.01


def test_inverse_sip_terms_follow_too():
    w = _sip_wcs(inverse=True)
    out = _aligned(w).wcs
    assert out.sip.ap is not None
    # the inverse terms of the output are the source's seen through the linear part:
    # ap'(v) = A ap(A^-1 v), as the forward ones
    lin = TRANSFORM.matrix[:2, :2]
    v = _grid() - 200.0
    u = v @ np.linalg.inv(lin).T
    expected = _poly(w.sip.ap, w.sip.bp, u) @ lin.T
    assert np.allclose(_poly(out.sip.ap, out.sip.bp, v), expected, rtol=1e-12, atol=1e-12)


def _poly(a, b, u):
    x, y = u[:, 0], u[:, 1]
    i, j = np.indices(a.shape)
    terms = x[:, None, None] ** i * y[:, None, None] ** j
    return np.column_stack([(terms * a).sum((1, 2)), (terms * b).sum((1, 2))])


def test_lookup_table_distortion_is_dropped_with_a_warning():
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [150.0, 2.0]
    w.wcs.crpix = [180.0, 140.0]
    w.wcs.cd = np.eye(2) / 3600.0
    table = np.full((8, 8), 0.5, np.float32)  # half a pixel everywhere
    w.cpdis1 = DistortionLookupTable(table, (1.0, 1.0), (1.0, 1.0), (64.0, 64.0))
    w.pixel_shape = (NX, NY)
    with pytest.warns(AstroalignWarning, match=r"lookup-table distortion.*off by up to 0\.5"):
        out = _aligned(w)
    assert out.wcs.cpdis1 is None
