# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Frames that `stack` must not combine as given: a file listed twice, a cube among images."""

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData

from astroalign_nd import AstroalignWarning, stack
from astroalign_nd.cli.main import main

from _helpers import write_sequence


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("frames")
    paths = write_sequence(folder, 3, seed=11, n_stars=40, noise_sigma=None)
    cube = folder / "cube.fits"
    fits.writeto(cube, np.stack([fits.getdata(paths[1])] * 3))
    return paths, str(cube)


def test_a_file_given_twice_is_stacked_once(files):
    paths, _ = files
    with pytest.warns(AstroalignWarning, match=r"f1.fits is given 2 times among the frames; "
                      "it is stacked once"):
        twice = stack([paths[0], paths[1], paths[1], paths[2]])
    once = stack(paths)
    assert twice.meta["NCOMBINE"] == once.meta["NCOMBINE"] == 3
    np.testing.assert_array_equal(twice.data, once.data)


def test_the_reference_listed_again_is_used_once(files):
    paths, _ = files
    with pytest.warns(AstroalignWarning, match="f0.fits is given 2 times"):
        st = stack(paths + [paths[0]], reference=paths[0])
    assert st.meta["NCOMBINE"] == 3


def test_a_cube_among_images_is_left_out_with_its_reason(files, tmp_path, capsys):
    paths, cube = files
    out = tmp_path / "stack.fits"
    code = main(["stack", *paths, cube, "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 1  # some frames failed; the others are stacked
    assert "LEFT OUT cube.fits" in captured.out + captured.err
    assert "not a 2-D image like the other frames" in captured.out + captured.err
    assert fits.getheader(out)["NCOMBINE"] == 3


@pytest.mark.parametrize("kwargs", [{}, {"drizzle": 2}])
def test_file_names_a_header_cannot_hold_are_escaped_in_it(files, tmp_path, kwargs):
    # A non-ASCII name, long enough to need CONTINUE cards, and a frame left out.
    names = [tmp_path / f"{'night_frame_' * 6}{k}_filtré_ñ.fits" for k in range(4)]
    for path, src in zip(names, files[0]):
        CCDData.read(src, unit="adu").write(path)
    CCDData(np.zeros((96, 96)), unit="adu").write(names[3], overwrite=True)
    out = tmp_path / "stack.fits"
    with pytest.warns(AstroalignWarning, match="left out of the stack"):
        stacked = stack([str(p) for p in names], output=out, **kwargs)
    header = fits.getheader(out)
    assert header["NCOMBINE"] == stacked.meta["NCOMBINE"] == 3
    assert header["IMCMB002"] == f"{'night_frame_' * 6}1_filtr\\xe9_\\xf1.fits"
    assert header["AAREJ001"].startswith(f"{'night_frame_' * 6}3_filtr\\xe9_\\xf1.fits: ")
