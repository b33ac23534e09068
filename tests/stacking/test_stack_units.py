# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Frames in other units: converted when astropy can, left out (and said) otherwise."""

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData

from astroalign_nd import AstroalignWarning, stack
from astroalign_nd.cli.main import main
from astroalign_nd.simulate import simulate_sequence


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    folder = tmp_path_factory.mktemp("units")
    seq = simulate_sequence((96, 96), n_frames=3, n_stars=40, seed=8)
    data = [np.asarray(f.data, dtype=np.float64) for f in seq.frames]

    def write(name, values, unit):
        path = folder / name
        CCDData(values, unit=unit).write(path)
        return str(path)

    return dict(jy=[write(f"f{k}_jy.fits", d, "Jy") for k, d in enumerate(data)],
                mjy=write("f2_mjy.fits", data[2] * 1000.0, "mJy"),
                adu=write("f2_adu.fits", data[2], "adu"),
                electron=write("f2_e.fits", data[2] * 1.7, "electron"))


def test_a_convertible_unit_is_converted_and_recorded(frames):
    same = stack(frames["jy"])
    mixed = stack(frames["jy"][:2] + [frames["mjy"]])
    assert mixed.unit == "Jy" and mixed.meta["NCOMBINE"] == 3
    np.testing.assert_allclose(mixed.data, same.data, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(mixed.uncertainty.array, same.uncertainty.array, rtol=1e-4)
    history = [str(h) for h in mixed.meta["HISTORY"]]
    assert any("f2_mjy.fits converted from mJy to Jy (x 0.001)" in h for h in history)


def test_an_inconvertible_unit_is_left_out_with_a_warning(frames):
    with pytest.warns(AstroalignWarning, match=r"f2_e.fits was left out of the stack: "
                      r".*unit 'electron' cannot be converted to the reference's 'Jy'"):
        st = stack(frames["jy"][:2] + [frames["electron"]])
    assert st.meta["NCOMBINE"] == 2 and st.meta["NREJECT"] == 1


def test_the_command_line_says_it_once(frames, tmp_path, capsys):
    out = tmp_path / "st.fits"
    code = main(["stack", *frames["jy"][:2], frames["adu"], "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 1
    assert "LEFT OUT f2_adu.fits: ValueError: its unit 'adu' cannot be converted" in \
        captured.out
    assert "was left out of the stack" not in captured.err  # the LEFT OUT line only
    assert fits.getheader(out)["BUNIT"] == "Jy"
