# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""On the command line every hint names a flag, never a Python keyword or None."""

import pytest
from astropy.io import fits

from astroalign_nd import register
from astroalign_nd.cli.errors import cli_words
from astroalign_nd.cli.main import main


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    folder = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--output-dir", str(folder)]) == 0
    return str(folder / "source.fits"), str(folder / "target.fits")


def _error(capsys, argv):
    code = main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


def test_order_as_a_number(demo, tmp_path, capsys):
    source, target = demo
    assert main(["register", source, target, "-o", str(tmp_path / "a.fits"),
                 "--order", "0"]) == 0


@pytest.mark.parametrize("argv, expected", [
    (["demo", "--output-dir", "{tmp}/d", "--seed", "-5"], "--seed must be an integer >= 0"),
    (["register", "{source}", "{target}", "-o", "{tmp}/a.fits", "--hdu", "5"],
     "Pass --hdu as an index"),
    (["register", "{source}", "{target}", "-o", "{tmp}/a.fits", "--bin-factor", "0"],
     "--bin-factor must be an integer >= 1 and <= 1024; got 0."),
    (["stack", "{source}", "{target}", "-o", "{tmp}/s.fits", "--memory-limit", "-1"],
     "--memory-limit must be a number of MB > 0"),
    (["stack", "{source}", "{target}", "-o", "{tmp}/s.fits", "--sigma-low", "-1"],
     "--sigma-low must be a finite number > 0; got -1.0."),
    (["watch", "{tmp}", "-r", "{target}", "--stack", "{tmp}/w.fits", "--clip", "minmax"],
     "a live stack's --clip must be one of 'sigma'"),
    (["watch", "{tmp}", "-r", "{target}", "--stack", "{tmp}/w.fits", "--interval", "-1"],
     "--interval must be a number of seconds > 0"),
    (["watch", "{tmp}", "-r", "{target}", "--stack", "{tmp}/w.fits", "--max-frames", "0"],
     "--max-frames must be 1 or more"),
])
def test_hints_name_flags(demo, tmp_path, capsys, argv, expected):
    source, target = demo
    argv = [a.format(source=source, target=target, tmp=tmp_path) for a in argv]
    code, err = _error(capsys, argv)
    assert code == 2
    assert err.count("\n") == 0 and expected in err
    assert "None" not in err and "  " not in err and "_" not in err.split(": ", 2)[-1]
    assert not (tmp_path / "w.fits").exists()  # refused before any work or output


def test_cli_words_leaves_no_python():
    assert cli_words("a.fits exists; pass overwrite=True (or --overwrite) to replace it.") == \
        "a.fits exists; pass --overwrite to replace it."
    assert cli_words("try more sources (n_sources)") == "try more sources (--n-sources)"


def test_a_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.fits"):
        register(str(tmp_path / "nope.fits"), str(tmp_path / "nope2.fits"))


@pytest.mark.parametrize("message, expected", [
    ("relax min_transparency (it left out 1), or pass select=None.",
     "relax --min-transparency (it left out 1), or pass --select none."),
    ("Leave such frames out, or use canvas='reference'.",
     "Leave such frames out, or use --canvas reference."),
    ("stack more frames, lower nlow/nhigh, or use clip='sigma'.",
     "stack more frames, lower --nlow/--nhigh, or use --clip sigma."),
    ("Use a lower degree (or degree='auto') or more stars.",
     "Use a lower degree (or --degree auto) or more stars."),
    ("skip_existing=True needs an output_dir.", "--skip-existing needs an --output-dir."),
    ("give aligned_dir a folder on another disk.", "give --aligned-dir a folder on another disk."),
])
def test_library_keywords_given_values_become_flags(message, expected):
    assert cli_words(message) == expected


def test_an_unknown_unit_and_a_selection_hint_name_flags(demo, tmp_path, capsys):
    source, target = demo
    bare = str(tmp_path / "bare.fits")  # no BUNIT: --unit says what its values are in
    fits.writeto(bare, fits.getdata(source))
    code, err = _error(capsys, ["register", bare, target, "-o", str(tmp_path / "a.fits"),
                                "--unit", "furlong"])
    assert code == 2
    assert err == ("astroalign-nd: error: --unit must be a unit astropy knows, such as 'adu', "
                   "'electron' or 'photon'; got 'furlong'.")
    code, err = _error(capsys, ["stack", source, target, "-o", str(tmp_path / "s.fits"),
                                "--min-transparency", "2"])
    assert code == 2 and "relax --min-transparency" in err and "pass --select none" in err
    assert "=" not in err and "_" not in err.split(": ", 2)[-1].split("Left out")[0]
    assert not (tmp_path / "s.fits").exists()
