# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Raw colour (Bayer) frames: registered on their grey versions, then demosaiced and stacked,
or Bayer-drizzled, into an RGB cube; on simulated frames with a known truth.
"""

import numpy as np
import pytest
from astropy.nddata import CCDData
from photutils.centroids import centroid_com

from _helpers import run_cli
from astroalign_nd import stack
from astroalign_nd.io import write_ccddata
from astroalign_nd.simulate import bayer_mosaic, dither_transforms, simulate_views
from astroalign_nd.stacking import colour
from astroalign_nd.stacking.colour import find_bayer_transform

SHAPE = (160, 200)


@pytest.fixture(scope="module")
def views():
    """Eight dithered, slightly rotated raw GRBG frames of one field (stars 2.2 raw px)."""
    ts = dither_transforms(8, max_shift=6.0, max_rotation=1.0, shape=SHAPE, seed=21)
    return simulate_views(ts, SHAPE, n_stars=90, fwhm=2.2, background=300.0,
                          flux_range=(3e3, 6e4), read_noise=5.0, seed=22)


@pytest.fixture(scope="module")
def raws(views):
    return [bayer_mosaic(f, "GRBG", gains=(0.6, 1.0, 0.8)) for f in views.frames]


def _grid_error(found, truth):
    yy, xx = np.mgrid[0:SHAPE[0]:20, 0:SHAPE[1]:20].astype(float)
    xf, yf = found(xx, yy)
    xt, yt = truth(xx, yy)
    return float(np.max(np.hypot(xf - xt, yf - yt)))


def test_colour_frame_registers_on_its_grey_version(views, raws):
    """
    The transform found on the grey version, in raw pixels, is the true one: within
    0.05 px on the balanced grey, within 1 px on the 2x2 superpixels (undersampled:
    their transform, converted to raw pixels, is an order of magnitude less precise).
    """
    for k in (1, 4, 7):
        t = find_bayer_transform(raws[k], raws[0])
        assert _grid_error(t, views.truth(k, 0)) < 0.05
        t = find_bayer_transform(raws[k], raws[0], grey="superpixel")
        assert _grid_error(t, views.truth(k, 0)) < 1.0


def _centroids(plane, xy, scale):
    """Centroids (reference pixels) of the stars at ``xy`` in a plane at ``scale``."""
    sky = np.nanmedian(plane)
    out = []
    for x, y in xy:
        cx, cy = scale * (x + 0.5) - 0.5, scale * (y + 0.5) - 0.5
        h = 3 * scale
        x0, y0 = int(round(cx)) - h, int(round(cy)) - h
        cut = plane[y0:y0 + 2 * h + 1, x0:x0 + 2 * h + 1] - sky
        if cut.shape != (2 * h + 1, 2 * h + 1) or not np.isfinite(cut).all():
            out.append((np.nan, np.nan))
            continue
        mx, my = centroid_com(np.clip(cut, 0, None))
        out.append(((x0 + mx + 0.5) / scale - 0.5, (y0 + my + 0.5) / scale - 0.5))
    return np.array(out)


def _bright_isolated(views):
    s = views.stars
    x, y, f = np.asarray(s["x"]), np.asarray(s["y"]), np.asarray(s["flux"])
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    np.fill_diagonal(d, np.inf)
    ok = (f > 5e3) & (d.min(axis=1) > 8) & (x > 15) & (x < SHAPE[1] - 16) & (y > 15) \
        & (y < SHAPE[0] - 16)
    return np.column_stack([x[ok], y[ok]])


@pytest.mark.parametrize("how", ["demosaic", "drizzle"])
def test_bayer_stack_has_no_colour_offset(views, raws, how, tmp_path):
    """
    Every colour of a star lands where the star is (the frames have no dispersion):
    the R-G and B-G centroid offsets are zero within 0.05 raw px, and the stack is an
    RGB cube with per-plane uncertainty and mask that CCDData.read reads back.
    """
    kw = dict(drizzle=2, pixfrac=1.0) if how == "drizzle" else dict(demosaic="bilinear")
    scale = 2 if how == "drizzle" else 1
    out = tmp_path / "rgb.fits"
    cube = stack(raws, bayer="auto", output=out, **kw)
    ny, nx = SHAPE[0] * scale, SHAPE[1] * scale
    assert cube.shape == (3, ny, nx) and cube.meta["NCOMBINE"] == 8
    assert cube.meta["AACHANS"] == "R,G,B" and "BAYERPAT" not in cube.meta
    xy = _bright_isolated(views)
    assert len(xy) >= 8
    cents = [_centroids(np.where(cube.mask[c], np.nan, cube.data[c]), xy, scale)
             for c in range(3)]
    ok = np.all([np.isfinite(c).all(axis=1) for c in cents], axis=0)
    assert ok.sum() >= 8
    # Registration: the green centroids are the true positions.
    assert np.median(np.hypot(*(cents[1][ok] - xy[ok]).T)) < 0.1
    for c in (0, 2):
        offset = np.median(cents[c][ok] - cents[1][ok], axis=0)
        assert np.all(np.abs(offset) < 0.05), (how, "RGB"[c], offset)
    back = CCDData.read(out)
    assert back.shape == (3, ny, nx)
    assert back.uncertainty.array.shape == (3, ny, nx) and back.mask.shape == (3, ny, nx)
    np.testing.assert_allclose(back.data, cube.data)
    assert np.all(np.isfinite(back.uncertainty.array[~back.mask]))


@pytest.mark.parametrize("how", ["demosaic", "drizzle"])
def test_bayer_stack_keeps_a_known_blue_offset(views, how):
    """
    A blue image 0.2 raw px to the right of green's (a dispersion along x, as in the
    Seestar frames: blue on odd rows, even columns in GRBG) comes out 0.2 px right of
    green in both stacks, within 0.05 px (the centroid box pulls slightly inward): a
    half-pixel error in where either path puts the blue pixels would show here.
    """
    from scipy.ndimage import shift

    blue = [shift(f.data, (0, 0.2), order=3, mode="nearest") for f in views.frames]
    raws = [bayer_mosaic(np.stack([f.data, f.data, b]), "GRBG", gains=(0.6, 1.0, 0.8))
            for f, b in zip(views.frames, blue)]
    kw = dict(drizzle=2, pixfrac=1.0) if how == "drizzle" else dict(demosaic="bilinear")
    scale = 2 if how == "drizzle" else 1
    cube = stack(raws, bayer="auto", **kw)
    xy = _bright_isolated(views)
    g, b = (_centroids(np.where(cube.mask[c], np.nan, cube.data[c]), xy, scale)
            for c in (1, 2))
    ok = np.isfinite(g).all(axis=1) & np.isfinite(b).all(axis=1)
    assert ok.sum() >= 8
    dx, dy = np.median(b[ok] - g[ok], axis=0)
    assert abs(dx - 0.2) < 0.05 and abs(dy) < 0.05, (how, dx, dy)


def test_bayer_options_are_checked(raws):
    with pytest.raises(ValueError, match="bayer must be one of 'auto', 'RGGB'.*got 'RGBG'"):
        stack(raws[:2], bayer="RGBG")
    with pytest.raises(ValueError, match="canvas='reference'"):
        stack(raws[:2], bayer="auto", canvas="union")
    with pytest.raises(ValueError, match="demosaic must be one of"):
        stack(raws[:2], bayer="auto", demosaic="AHD")
    with pytest.raises(ValueError, match="no BAYERPAT"):
        stack([CCDData(r.data, unit="adu") for r in raws[:2]], bayer="auto", drizzle=2)
    with pytest.raises(ValueError, match="pixfrac"):
        stack(raws[:2], bayer="auto", drizzle=2, pixfrac=1.5)


def test_aligned_dir_with_raw_colour_frames(raws, tmp_path):
    """
    Demosaiced, each frame's registered red, green and blue planes are kept in
    ``aligned_dir``; the Bayer drizzle, which makes no registered frame, refuses it
    before any work instead of ignoring it (and leaves no folder behind).
    """
    kept = tmp_path / "aligned"
    cube = stack(raws[:3], bayer="auto", demosaic="bilinear", aligned_dir=kept)
    names = sorted(p.name for p in kept.iterdir())
    assert names == ["frame00001_B.fits", "frame00001_G.fits", "frame00001_R.fits",
                     "frame00002_B.fits", "frame00002_G.fits", "frame00002_R.fits",
                     "reference_B.fits", "reference_G.fits", "reference_R.fits"]
    # The reference's green plane, not resampled, keeps its raw green pixels (GRBG; the
    # edge rows and columns aside, where the demosaicing's kernel meets the border).
    green = CCDData.read(kept / "reference_G.fits")
    assert green.shape == cube.shape[1:]
    raw = np.asarray(raws[0].data, float)
    for r0, c0 in ((2, 2), (1, 1)):
        np.testing.assert_allclose(green.data[r0:-2:2, c0:-2:2], raw[r0:-2:2, c0:-2:2],
                                   rtol=1e-6)
    with pytest.raises(ValueError, match="aligned_dir cannot be kept with bayer and drizzle"):
        stack(raws[:3], bayer="auto", drizzle=2, aligned_dir=tmp_path / "none")
    assert not (tmp_path / "none").exists()


def test_command_line_bayer_drizzle(raws, tmp_path):
    """``astroalign-nd stack --bayer GRBG --drizzle 2``: an RGB cube at twice the size."""
    paths = []
    for k, raw in enumerate(raws[:3]):
        paths.append(tmp_path / f"raw{k}.fits")
        write_ccddata(raw, paths[-1])
    out = tmp_path / "rgb.fits"
    code, stdout, _ = run_cli("stack", *paths, "-o", out, "--bayer", "GRBG", "--drizzle", 2,
                              "--pixfrac", 1.0)
    assert code == 0 and "3 frames combined" in stdout
    assert "[1/2] raw1.fits: registered (" in stdout and "[2/2] raw2.fits: registered (" in stdout
    cube = CCDData.read(out)
    assert cube.shape == (3, 2 * SHAPE[0], 2 * SHAPE[1]) and cube.meta["AABAYER"] == "GRBG"
    code, _, stderr = run_cli("stack", *paths, "-o", tmp_path / "x.fits", "--bayer", "CYMG")
    assert code == 2 and "invalid choice: 'CYMG'" in stderr


@pytest.mark.parametrize("extra", [[], ["--drizzle", "2"]])
def test_ctrl_c_in_a_bayer_stack_writes_the_partial_stack(raws, tmp_path, monkeypatch, extra):
    """Interrupted while the fourth frame is registered: the first three are the stack."""
    paths = []
    for k, raw in enumerate(raws[:5]):
        paths.append(tmp_path / f"raw{k}.fits")
        write_ccddata(raw, paths[-1])
    real, calls = colour.find_transform, []

    def find_transform(*args, **kwargs):  # Ctrl-C while the fourth frame is registered
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt("SIGINT")
        return real(*args, **kwargs)

    monkeypatch.setattr(colour, "find_transform", find_transform)
    out = tmp_path / "rgb.fits"
    code, stdout, err = run_cli("stack", *paths, "-o", out, "--bayer", "GRBG", "--no-progress",
                                *extra)
    assert code == 130 and "Traceback" not in err
    cube = CCDData.read(out)
    assert cube.meta["NCOMBINE"] == 3 and cube.meta["NREJECT"] == 0
    assert [cube.meta[f"IMCMB{k:03d}"] for k in (2, 3)] == ["raw1.fits", "raw2.fits"]
    history = [line for line in cube.meta["HISTORY"] if line.startswith("partial stack")]
    assert history == ["partial stack (interrupted): 3 of 5 frames stacked, 2 not registered"]
    assert history[0] in stdout and "partial stack: 3 frames combined" in stdout
    assert np.isfinite(cube.data[:, ~cube.mask.any(axis=0)]).all()


def test_the_reference_header_comments_are_kept(raws):
    """The colour stack's header is the reference's, COMMENT cards included (no warning)."""
    from astropy.io import fits

    frames = []
    for raw in raws[:3]:
        header = fits.Header({"OBJECT": "field", "BAYERPAT": "GRBG"})
        header["COMMENT"] = "taken automatically"
        frames.append(CCDData(raw.data, unit=raw.unit, meta=header))
    cube = stack(frames, bayer="auto", drizzle=2)
    assert list(cube.meta["COMMENT"]) == ["taken automatically"]
    assert cube.meta["OBJECT"] == "field" and "BAYERPAT" not in cube.meta


def _with_trail_and_cosmics(raw):
    """``raw`` with a satellite trail (a line of +2000 adu) and 12 cosmic rays (+5000)."""
    data = np.array(raw.data, dtype=float)
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    data[np.abs(0.45 * xx - yy + 40.0) / np.hypot(0.45, 1.0) < 0.8] += 2000.0
    rng = np.random.default_rng(5)
    data[rng.integers(5, SHAPE[0] - 5, 12), rng.integers(5, SHAPE[1] - 5, 12)] += 5000.0
    return CCDData(data, unit=raw.unit, meta=raw.meta), int((data - raw.data > 0).sum())


@pytest.mark.parametrize("clip", ["sigma", None])
def test_bayer_drizzle_rejects_a_trail_and_cosmic_rays(raws, clip):
    """
    A satellite trail and cosmic rays in one of six frames: with the stack's rejection
    (found on the grey versions, blotted back onto the raw frame) nothing of them is
    left above 5 sigma of the stack of the clean frames on the sky that every frame
    covers; with ``clip=None`` hundreds of pixels are.
    """
    frames = list(raws[:6])
    frames[3], n_hit = _with_trail_and_cosmics(frames[3])
    kw = dict(bayer="auto", drizzle=2, pixfrac=1.0, clip=clip)
    clean, cube = stack(raws[:6], **kw), stack(frames, **kw)
    inner = np.zeros(clean.shape, bool)
    inner[:, 20:-20, 20:-20] = True  # 10 raw px in: every frame there (dithers up to 8 px)
    sigma = clean.uncertainty.array
    sky = np.nanmedian(np.where(inner & ~clean.mask, clean.data, np.nan), axis=(1, 2))
    on_sky = inner & ~(clean.mask | cube.mask) & (clean.data < sky[:, None, None] + 5 * sigma)
    excess = (cube.data - clean.data)[on_sky] / sigma[on_sky]
    history = " ".join(cube.meta["HISTORY"])
    n_rejected = [cube.meta[f"AANRJ{k:03d}"] for k in range(1, 7)]
    if clip is None:
        assert excess.max() > 50 and (excess > 5).sum() > 500
        assert "no rejection" in history and n_rejected == [0] * 6
    else:
        assert excess.max() < 5, excess.max()
        assert "outliers rejected" in history and cube.meta["AASTKCLP"] == "sigma"
        # The defects' raw pixels (and their neighbours that blot back) weigh nothing,
        # beyond what the clean frames lose (noise and star-core outliers).
        extra = n_rejected[3] - np.median(n_rejected[:3] + n_rejected[4:])
        assert n_hit <= extra < 5 * n_hit, (n_hit, n_rejected)


def test_detection_options_reach_the_reference_too(raws):
    """The user's detection options detect the reference's grey version as well as
    each frame's: with a fixed ``fwhm`` both detections report that width."""
    ref, pattern = colour._raw_frame(raws[0], "GRBG", None, None, "reference")
    fwhms = {}
    found = list(colour._find_raw_transforms([((raws[1], "one"), 1)], ref, pattern, "GRBG",
                                             None, None, {"fwhm": 3.7}, fwhms=fwhms))
    assert found[0][5] is None  # registered
    assert fwhms == {1: pytest.approx(3.7), None: pytest.approx(3.7)}
