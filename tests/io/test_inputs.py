# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
One input parser for every entry point: FITS files read as CCDData.read
reads them (mask, every uncertainty class, flags, unit), extensions,
reproject-style tuples, masked catalogs, ImageFileCollection and
generators, through register, the CLI and register_batch.
"""

import gc
import os
import warnings
import weakref

import numpy as np
import pytest
from astropy import log
from astropy import units as u
from astropy.io import fits
from astropy.nddata import (CCDData, InverseVariance, StdDevUncertainty,
                            VarianceUncertainty)
from astropy.table import MaskedColumn, Table
from astropy.utils.exceptions import AstropyUserWarning
from astropy.wcs import WCS

import astroalign_nd
from astroalign_nd import (AstroalignWarning, PoorFitWarning, Reference, TooFewSourcesError,
                           apply_transform, find_sources, find_transform, register,
                           register_batch)
from astroalign_nd.cli import main
from astroalign_nd.simulate import simulate_pair

from _helpers import frame_error, run_cli

UNCERTAINTIES = [StdDevUncertainty, VarianceUncertainty, InverseVariance]


@pytest.fixture(scope="module")
def pair():
    return simulate_pair((160, 160), n_stars=80, rotation=17.0, scale=1.05,
                         translation=(3.3, -2.1), flux_range=(2e3, 2e5), seed=11)


def _mask_and_flags(shape):
    mask = np.zeros(shape, bool)
    mask[40:52, 60:72] = True
    flags = np.zeros(shape, np.int16)
    flags[80:92, 20:32] = 4
    flags[100:106, 100:106] = 9
    return mask, flags


def _uncertainty(cls, data):
    var = np.clip(data, 0, None) + 25.0
    if cls is StdDevUncertainty:
        return cls(np.sqrt(var))
    if cls is VarianceUncertainty:
        return cls(var)
    return cls(1.0 / var)


def _source_ccd(pair, cls):
    mask, flags = _mask_and_flags(pair.source.shape)
    return CCDData(pair.source.copy(), unit="electron", mask=mask, flags=flags,
                   uncertainty=_uncertainty(cls, pair.source),
                   meta={"OBJECT": "M 42", "EXPTIME": 30.0})


def _write(ccd, path):
    ccd.write(path, hdu_flags="FLAGS")
    return str(path)


@pytest.fixture(scope="module")
def target_file(pair, tmp_path_factory):
    path = tmp_path_factory.mktemp("target") / "target.fits"
    CCDData(pair.target.copy(), unit="electron").write(path)
    return str(path)


def _assert_same_frame(out, expected, cls):
    """A registered frame from a file equals the one from the same CCDData in memory."""
    assert out.shape == expected.shape
    assert out.unit == u.electron
    np.testing.assert_array_equal(out.mask, expected.mask)
    assert type(out.uncertainty) is cls
    np.testing.assert_allclose(out.uncertainty.array, expected.uncertainty.array,
                               rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(out.data, expected.data, rtol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(out.flags, expected.flags)
    assert out.meta["OBJECT"] == "M 42"


def _check_flags_and_mask_follow(out, pair):
    """Flags and mask land where the true transform puts them."""
    mask, flags = _mask_and_flags(pair.source.shape)
    for (y, x), value in (((85, 25), 4), ((102, 102), 9)):
        xt, yt = pair.transform(float(x), float(y))
        assert out.flags[int(round(float(yt))), int(round(float(xt)))] == value
    xt, yt = pair.transform(65.0, 45.0)
    assert out.mask[int(round(float(yt))), int(round(float(xt)))]
    # Flagged area is kept (nearest neighbour: about the source area times scale**2).
    assert 0.7 < np.sum(out.flags == 4) / (144 * 1.05**2) < 1.3


# -- register by path -------------------------------------------------------------------------


@pytest.mark.parametrize("cls", UNCERTAINTIES)
def test_register_path_keeps_mask_uncertainty_flags_unit(pair, tmp_path, target_file, cls):
    ccd = _source_ccd(pair, cls)
    path = _write(ccd, tmp_path / "src.fits")
    expected = register(ccd, pair.target)
    out = register(path, target_file)
    _assert_same_frame(out, expected, cls)
    _check_flags_and_mask_follow(out, pair)
    # and it survives writing and reading back
    out.write(tmp_path / "out.fits", hdu_flags="FLAGS")
    back = CCDData.read(tmp_path / "out.fits", hdu_flags="FLAGS")
    _assert_same_frame(back, expected, cls)


def test_apply_transform_and_reference_by_path(pair, tmp_path, target_file):
    ccd = _source_ccd(pair, VarianceUncertainty)
    path = _write(ccd, tmp_path / "src.fits")
    ref = Reference(target_file)
    t, _ = find_transform(path, ref)
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1
    out = apply_transform(t, path, target_file)
    _assert_same_frame(out, apply_transform(t, ccd, pair.target), VarianceUncertainty)


def test_unit_fallback_and_bunit(pair, tmp_path):
    plain = tmp_path / "plain.fits"
    fits.PrimaryHDU(pair.source.copy()).writeto(plain)
    assert register(str(plain), pair.target).unit == u.adu
    assert register(str(plain), pair.target, unit="electron").unit == u.electron
    assert register(str(plain), pair.target, unit=u.ph).unit == u.ph
    # BUNIT wins over the fallback, as its name says
    with_bunit = tmp_path / "bunit.fits"
    fits.PrimaryHDU(pair.source.copy(), header=fits.Header({"BUNIT": "ADU"})).writeto(
        with_bunit)
    assert register(str(with_bunit), pair.target, unit="electron").unit == u.adu
    bad = tmp_path / "bad.fits"
    fits.PrimaryHDU(pair.source.copy(), header=fits.Header({"BUNIT": "furlongs/fortnite"})
                    ).writeto(bad)
    # a BUNIT astropy does not know is kept as written (registration needs no unit)
    out = register(str(bad), pair.target)
    assert isinstance(out.unit, u.UnrecognizedUnit)
    assert out.unit.to_string() == "furlongs/fortnite"
    out.write(tmp_path / "out.fits")
    with fits.open(tmp_path / "out.fits") as hdul:
        assert hdul[0].header["BUNIT"] == "furlongs/fortnite"
    # and astropy's list of known misspellings is used as CCDData.read uses it
    fixed = tmp_path / "electrons.fits"
    fits.PrimaryHDU(pair.source.copy(), header=fits.Header({"BUNIT": "ELECTRONS/S"})
                    ).writeto(fixed)
    assert register(str(fixed), pair.target).unit == u.electron / u.s


# -- command line ----------------------------------------------------------------------------


def test_cli_keeps_everything(pair, tmp_path, target_file):
    ccd = _source_ccd(pair, StdDevUncertainty)
    src = _write(ccd, tmp_path / "src.fits")
    out = tmp_path / "out.fits"
    code, _, err = run_cli("register", src, target_file, "-o", out)
    assert code == 0, err
    assert err == ""
    with fits.open(out) as hdul:
        assert [h.name for h in hdul] == ["PRIMARY", "MASK", "UNCERT", "FLAGS"]
    back = CCDData.read(out, hdu_flags="FLAGS")
    _assert_same_frame(back, register(ccd, pair.target), StdDevUncertainty)


@pytest.mark.parametrize("cls", [VarianceUncertainty, InverseVariance])
def test_cli_register_and_batch_in_process(pair, tmp_path, target_file, cls, capsys):
    ccd = _source_ccd(pair, cls)
    src = _write(ccd, tmp_path / "src.fits")
    expected = register(ccd, pair.target)
    assert main(["register", src, target_file, "-o", str(tmp_path / "one.fits")]) == 0
    _assert_same_frame(CCDData.read(tmp_path / "one.fits", hdu_flags="FLAGS"), expected, cls)
    assert main(["batch", target_file, src, "--output-dir", str(tmp_path / "b")]) == 0
    _assert_same_frame(CCDData.read(tmp_path / "b" / "src_aligned.fits", hdu_flags="FLAGS"),
                       expected, cls)
    capsys.readouterr()


def test_cli_hdu_option(pair, tmp_path, capsys):
    # --hdu applies to every file, the target's too
    path = tmp_path / "mef.fits"
    _multi_extension(pair).writeto(path)
    target_file = str(tmp_path / "mef_target.fits")
    _multi_extension(pair, pair.target).writeto(target_file)
    out = tmp_path / "out.fits"
    assert main(["register", str(path), target_file, "-o", str(out), "--hdu", "SCI"]) == 0
    assert CCDData.read(out).meta["EXTNAME"] == "SCI"
    assert main(["register", str(path), target_file, "-o", str(out), "--overwrite",
                 "--hdu", "2"]) == 0
    assert main(["register", str(path), target_file, "-o", str(out), "--overwrite",
                 "--hdu", "NOPE"]) == 2
    assert "has no HDU 'NOPE'" in capsys.readouterr().err
    # batch: every frame and the target read from that extension
    assert main(["batch", str(path), "-r", target_file, "--output-dir", str(tmp_path / "b"),
                 "--hdu", "SCI2"]) == 0
    assert CCDData.read(tmp_path / "b" / "mef_aligned.fits").meta["EXTNAME"] == "SCI2"
    capsys.readouterr()


# -- register_batch ---------------------------------------------------------------------------


@pytest.mark.parametrize("cls", UNCERTAINTIES)
def test_register_batch_paths_keep_everything(pair, tmp_path, target_file, cls):
    ccd = _source_ccd(pair, cls)
    src = _write(ccd, tmp_path / "night1.fits")
    expected = register(ccd, pair.target)
    result = register_batch([src], target_file, output_dir=tmp_path / "out")
    assert result.frames[0].ok, result.frames[0].error
    assert result.frames[0].name == "night1.fits"
    back = CCDData.read(tmp_path / "out" / "night1_aligned.fits", hdu_flags="FLAGS")
    _assert_same_frame(back, expected, cls)
    # in memory too
    mem = register_batch([src], target_file).frames[0].ccd
    _assert_same_frame(mem, expected, cls)


def _collection_dir(pair, tmp_path):
    folder = tmp_path / "raw"
    folder.mkdir()
    rot = np.rot90(pair.source).copy()
    for name, data, obj in (("a.fits", pair.source, "FIELD"), ("b.fits", rot, "FIELD"),
                            ("flat.fits", np.ones((160, 160)), "FLAT")):
        CCDData(data.copy(), unit="adu", meta={"OBJECT": obj}).write(folder / name)
    return folder


def test_image_file_collection(pair, tmp_path):
    ccdproc = pytest.importorskip("ccdproc")
    folder = _collection_dir(pair, tmp_path)
    ifc = ccdproc.ImageFileCollection(folder).filter(object="FIELD")
    result = register_batch(ifc, pair.target, output_dir=tmp_path / "out")
    assert [f.name for f in result.frames] == ["a.fits", "b.fits"]
    assert all(f.ok for f in result.frames), result.summary()
    assert sorted(os.listdir(tmp_path / "out")) == ["a_aligned.fits", "b_aligned.fits"]
    assert frame_error(result.frames[0].transform, pair.truth_matrix, (160, 160)) < 0.1
    # ifc.ccds(return_fname=True) keeps the names too
    result = register_batch(ifc.ccds(return_fname=True), pair.target)
    assert [f.name for f in result.frames] == ["a.fits", "b.fits"]
    # an unfiltered collection: the flat fails, the others go on
    everything = ccdproc.ImageFileCollection(folder)
    result = register_batch(everything, pair.target)
    assert sorted(f.name for f in result.succeeded) == ["a.fits", "b.fits"]
    assert [f.name for f in result.failed] == ["flat.fits"]


def test_image_file_collection_ext(pair, tmp_path):
    ccdproc = pytest.importorskip("ccdproc")
    folder = tmp_path / "mef"
    folder.mkdir()
    _multi_extension(pair).writeto(folder / "x.fits")
    ifc = ccdproc.ImageFileCollection(folder, ext="SCI")
    result = register_batch(ifc, pair.target)
    assert result.frames[0].ok, result.summary()
    assert result.frames[0].ccd.meta["EXTNAME"] == "SCI"


def test_generator_is_consumed_one_frame_at_a_time(pair, tmp_path):
    refs = []

    def frames():
        for k in range(4):
            if k >= 2:
                gc.collect()
                # the frame before last is no longer held by the batch
                assert refs[k - 2]() is None
            ccd = CCDData(pair.source.copy(), unit="adu")
            refs.append(weakref.ref(ccd))
            yield ccd

    result = register_batch(frames(), pair.target, output_dir=tmp_path / "out")
    assert [f.name for f in result.frames] == ["frame0", "frame1", "frame2", "frame3"]
    assert all(f.ok for f in result.frames)
    gen_paths = (str(p) for p in [_write(CCDData(pair.source.copy(), unit="adu"),
                                         tmp_path / "g.fits")] * 2)
    result = register_batch(gen_paths, pair.target)
    # the n-th use of a name is shown as name#n, as a list shows it (and as
    # its output is renamed <stem>_n<suffix>.fits)
    assert [f.name for f in result.frames] == ["g.fits", "g.fits#2"]


def test_batch_bad_sources(pair):
    with pytest.raises(TypeError, match="single path"):
        register_batch("frame.fits", pair.target)
    with pytest.raises(TypeError, match="iterable"):
        register_batch(42, pair.target)


# -- tuples and extensions -------------------------------------------------------------------


def _tan_wcs(crval=(10.0, 20.0)):
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crpix = [80.0, 80.0]
    w.wcs.crval = list(crval)
    w.wcs.cdelt = [-1e-4, 1e-4]
    return w


def test_array_header_and_array_wcs_tuples(pair):
    t0, _ = find_transform(pair.source, pair.target)
    hdr = _tan_wcs().to_header()
    hdr["BUNIT"] = "electron"
    hdr["OBJECT"] = "tuple"
    t1, _ = find_transform((pair.source, hdr), (pair.target, _tan_wcs((10.01, 20.0))))
    np.testing.assert_allclose(t1.matrix, t0.matrix, atol=1e-9)
    out = register((pair.source, hdr), (pair.target, _tan_wcs((10.01, 20.0))))
    assert out.unit == u.electron
    assert out.meta["OBJECT"] == "tuple"
    assert out.wcs.wcs.crval[0] == pytest.approx(10.01)
    # a masked array inside the tuple keeps its mask
    masked = np.ma.MaskedArray(pair.source, mask=np.zeros(pair.source.shape, bool))
    masked.mask[40:52, 60:72] = True
    out = register((masked, hdr), pair.target)
    xt, yt = pair.transform(65.0, 45.0)
    assert out.mask[int(round(float(yt))), int(round(float(xt)))]
    # the header is the caller's: not modified
    assert "AATTYPE" not in hdr
    with pytest.raises(TypeError, match="first element"):
        register((CCDData(pair.source, unit="adu"), hdr), pair.target)


def _multi_extension(pair, image=None):
    """PRIMARY holds an unrelated image; SCI (ext 1) the source; ext 2 the source too."""
    image = pair.source if image is None else image
    noise = np.random.default_rng(5).normal(100.0, 5.0, pair.source.shape)
    return fits.HDUList([
        fits.PrimaryHDU(noise),
        fits.ImageHDU(image.copy(), name="SCI"),
        fits.ImageHDU(image.copy(), name="SCI2"),
        fits.BinTableHDU(Table({"x": [1.0]}), name="CAT"),
    ])


def test_choose_extension(pair, tmp_path):
    path = tmp_path / "mef.fits"
    hdul = _multi_extension(pair)
    hdul.writeto(path)
    with pytest.raises(TooFewSourcesError):
        find_transform(str(path), pair.target)  # the first image: noise
    for hdu in ("SCI", 1, ("SCI2", 1), 2):
        t, _ = find_transform(str(path), pair.target, hdu=hdu)
        assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1
    t, _ = find_transform(hdul, pair.target, hdu="SCI")
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1
    assert Reference(str(path), hdu="SCI").shape == (160, 160)
    assert len(find_sources(hdul["SCI"])) > 20
    with pytest.raises(ValueError, match="no HDU 'DQ'"):
        find_transform(str(path), pair.target, hdu="DQ")
    with pytest.raises(ValueError, match="holds no image"):
        find_transform(str(path), pair.target, hdu="CAT")
    with pytest.raises(ValueError, match="no HDU 9"):
        register(str(path), pair.target, hdu=9)


def test_extension_only_file_merges_primary_header(pair, tmp_path):
    path = tmp_path / "ext.fits"
    fits.HDUList([fits.PrimaryHDU(header=fits.Header({"TELESCOP": "T1"})),
                  fits.ImageHDU(pair.source.copy(), name="SCI",
                                header=fits.Header({"BUNIT": "electron"}))]).writeto(path)
    out = register(str(path), pair.target)
    assert out.unit == u.electron
    assert out.meta["TELESCOP"] == "T1" and out.meta["EXTNAME"] == "SCI"


# -- find_sources honours every input's mask -----------------------------------------------


def test_find_sources_inputs_and_masks(pair, tmp_path):
    mask = np.zeros(pair.source.shape, bool)
    mask[:, :80] = True
    expected = find_sources(pair.source, mask=mask)
    assert len(expected) > 10 and np.all(expected["x"] >= 80)
    ccd = CCDData(pair.source.copy(), unit="adu", mask=mask)
    path = str(tmp_path / "masked.fits")
    ccd.write(path)
    kinds = {
        "ccddata": ccd,
        "masked": np.ma.MaskedArray(pair.source, mask=mask),
        "path": path,
        "tuple": (np.ma.MaskedArray(pair.source, mask=mask), fits.Header()),
    }
    for kind, obj in kinds.items():
        got = find_sources(obj)
        np.testing.assert_allclose(got["x"], expected["x"], err_msg=kind)
        np.testing.assert_allclose(got["y"], expected["y"], err_msg=kind)
    # the user's mask is combined with the input's own
    extra = np.zeros(pair.source.shape, bool)
    extra[:80, :] = True
    got = find_sources(ccd, mask=extra)
    np.testing.assert_allclose(got["x"], find_sources(pair.source, mask=mask | extra)["x"])
    with pytest.raises(ValueError, match="mask shape"):
        find_sources(ccd, mask=np.zeros((3, 3), bool))
    with pytest.raises(TypeError, match="catalog"):
        find_sources(Table({"x": [1.0], "y": [2.0]}))


def test_masked_catalog_entries_are_not_positions(pair):
    src = find_sources(pair.source, n_sources=60)
    dst = find_sources(pair.target, n_sources=60)
    t0, _ = find_transform(src, dst)
    # Garbage positions, masked: a catalog with missing measurements.
    bad = Table(src, masked=True, copy=True)
    for k in (0, 3, 7):
        bad.insert_row(k, {"x": -1e6, "y": 3e7})
    bad["x"] = MaskedColumn(bad["x"], mask=(bad["x"] == -1e6))
    bad["y"] = MaskedColumn(bad["y"], mask=(bad["y"] == 3e7))
    t1, (s, _) = find_transform(bad, dst)
    np.testing.assert_allclose(t1.matrix, t0.matrix, atol=1e-9)
    assert np.all(s[:, 0] > -1e5)
    # a masked (N, 2) array of positions too
    arr = np.ma.MaskedArray(np.column_stack([bad["x"].data, bad["y"].data]),
                            mask=np.column_stack([bad["x"].mask, bad["y"].mask]))
    t2, _ = find_transform(arr, dst)
    np.testing.assert_allclose(t2.matrix, t0.matrix, atol=1e-9)


# -- astropy's conventions -------------------------------------------------------------------


def test_warning_classes_and_caller_line():
    assert issubclass(AstroalignWarning, AstropyUserWarning)
    assert issubclass(PoorFitWarning, AstropyUserWarning)
    # An affine field fitted with a similarity: the warning points at this line.
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 500, (60, 2))
    dst = src @ np.array([[1.0, 0.0], [0.0, 1.04]]).T + 5.0
    with pytest.warns(PoorFitWarning) as record:
        find_transform(src, dst, transform_type="similarity")
    assert {os.path.basename(w.filename) for w in record} == {"test_inputs.py"}


def test_no_per_frame_third_party_warnings(pair, tmp_path):
    # A non-standard WCS that astropy fixes (FITSFixedWarning) and a blank frame
    # (photutils' NoDetectionsWarning): neither may leak.  Warnings are errors here.
    hdr = _tan_wcs().to_header()
    hdr["RADECSYS"] = "FK5"
    hdr["MJD-OBS"] = 50000.0
    hdr["DATE-OBS"] = "1995-10-10"
    path = tmp_path / "fixable.fits"
    fits.PrimaryHDU(pair.source.copy(), header=hdr).writeto(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = register(str(path), pair.target)
        assert out.shape == (160, 160)
        register((pair.source, hdr), pair.target)
        # noise and cosmic rays: photutils finds peaks, but none pass its filters
        rng = np.random.default_rng(5)
        blank = rng.normal(100.0, 5.0, (160, 160))
        ys, xs = rng.integers(0, 160, (2, 20))
        blank[ys, xs] += rng.uniform(50, 500, 20)
        with pytest.raises(TooFewSourcesError):
            find_transform(blank, pair.target)
        result = register_batch([blank, str(path)], pair.target)
    assert [f.ok for f in result.frames] == [False, True]


def test_search_progress_goes_to_the_astropy_logger(pair):
    level = log.level
    log.setLevel("DEBUG")
    try:
        with log.log_to_list() as messages:
            find_transform(pair.source, pair.target)
    finally:
        log.setLevel(level)
    text = [m.message for m in messages if m.levelname == "DEBUG"]
    assert any("attempt 1" in m for m in text)
    assert any("match found" in m for m in text)


def test_add_keyword_opt_out(pair):
    out = register(pair.source, pair.target, add_keyword=False)
    assert not any(k.startswith("AAT") for k in out.meta)
    assert "HISTORY" not in out.meta
    out = register(CCDData(pair.source, unit="adu", meta={"OBJECT": "x"}), pair.target)
    from astroalign_nd.io.header import QUALITY_KEYWORDS

    for suffix, *_ in QUALITY_KEYWORDS:
        assert "AAT" + suffix in out.meta


def test_public_api_is_typed():
    import inspect
    from importlib.resources import files

    assert files("astroalign_nd").joinpath("py.typed").is_file()
    for func in (register, find_transform, apply_transform, register_batch,
                 astroalign_nd.transform_to_header, astroalign_nd.transform_from_header,
                 astroalign_nd.SimilarityTransform.from_points):
        sig = inspect.signature(func)
        assert sig.return_annotation is not inspect.Signature.empty, func.__name__


def test_long_meta_keywords_are_kept_as_hierarch(pair, tmp_path):
    # ccdproc records its steps under keys longer than 8 characters.
    ccd = CCDData(pair.source, unit="adu",
                  meta={"subtract_bias": "ccd=<CCDData>, master=<CCDData>", "OBJECT": "x",
                        "exptime": 30.0})
    out = register(ccd, pair.target)
    assert out.meta["subtract_bias"] == "ccd=<CCDData>, master=<CCDData>"
    assert out.meta["EXPTIME"] == 30.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out.write(tmp_path / "out.fits")
    assert CCDData.read(tmp_path / "out.fits").meta["subtract_bias"].startswith("ccd=")


def test_unparsable_wcs_cards_do_not_survive(pair, tmp_path):
    # They described the source's pixel grid; after registration they would lie.
    hdr = fits.Header({"CTYPE1": "RA---XXX", "CTYPE2": "DEC--XXX", "CRPIX1": 1.0,
                       "CRPIX2": 1.0, "CRVAL1": 10.0, "CRVAL2": 20.0, "CDELT1": 1e-3,
                       "CDELT2": 1e-3, "OBJECT": "kept"})
    path = tmp_path / "badwcs.fits"
    fits.PrimaryHDU(pair.source.copy(), header=hdr).writeto(path)
    out = register(str(path), pair.target)
    assert out.wcs is None
    assert out.meta["OBJECT"] == "kept"
    for key in ("CTYPE1", "CRPIX1", "CRVAL2", "CDELT2"):
        assert key not in out.meta


@pytest.mark.parametrize("cls", UNCERTAINTIES)
def test_hdulist_in_memory_keeps_extensions(pair, tmp_path, cls):
    ccd = _source_ccd(pair, cls)
    path = _write(ccd, tmp_path / "src.fits")
    with fits.open(path) as hdul:
        out = register(hdul, pair.target)
    expected = register(ccd, pair.target)
    _assert_same_frame(out, expected, cls)


def test_fits_paths_read_in_native_order_and_register_as_arrays(tmp_path):
    # FITS data are big-endian: a file read here is swapped in place (no second
    # copy), and registering the files gives the arrays' result bit for bit.
    from astroalign_nd.io.read import parse_input

    pair = simulate_pair((256, 256), n_stars=120, rotation=20.0, seed=4)
    src = pair.source.astype(np.float32)
    dst = pair.target.astype(np.float32)
    ps, pt = tmp_path / "s.fits", tmp_path / "t.fits"
    fits.writeto(ps, src)
    fits.writeto(pt, dst)
    before = (ps.read_bytes(), pt.read_bytes())
    parsed = parse_input(str(ps), "source")
    assert parsed.data.dtype.isnative and parsed.data.dtype == np.float32
    np.testing.assert_array_equal(parsed.data, src)
    from_files = astroalign_nd.register(str(ps), str(pt))
    from_arrays = astroalign_nd.register(src, dst)
    np.testing.assert_array_equal(from_files.data, from_arrays.data)
    np.testing.assert_array_equal(from_files.mask, from_arrays.mask)
    assert (ps.read_bytes(), pt.read_bytes()) == before  # files untouched


def test_register_keeps_a_reference_target_whole():
    # register frees the pixels of a target it read itself, never those of a
    # Reference (or array) the caller holds.
    pair = simulate_pair((256, 256), n_stars=120, rotation=20.0, seed=4)
    dst = pair.target.astype(np.float32)
    ref = Reference(dst)
    first = astroalign_nd.register(pair.source, ref)
    assert ref._parsed.data is not None and ref._parsed.data.shape == dst.shape
    second = astroalign_nd.register(pair.source, ref)
    np.testing.assert_array_equal(first.data, second.data)
    np.testing.assert_array_equal(ref._parsed.data, pair.target.astype(np.float32))
