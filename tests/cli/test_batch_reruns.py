# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""`astroalign-nd batch`: the reference among the images, and a second run into one folder."""

import os

import pytest

from astroalign_nd.cli.main import main


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    folder = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--output-dir", str(folder)]) == 0
    return str(folder / "source.fits"), str(folder / "target.fits")


def test_the_reference_among_the_images_is_written_once(demo, tmp_path, capsys):
    source, target = demo
    out = tmp_path / "aligned"
    capsys.readouterr()
    # The documented usage with a glob that also matches the reference.
    assert main(["batch", source, target, "-r", target, "--output-dir", str(out)]) == 0
    printed = capsys.readouterr().out
    assert sorted(os.listdir(out)) == ["source_aligned.fits", "target_reference.fits"]
    assert "is among the images: it is written once" in printed
    assert "1 of 1 frames registered" in printed


def test_a_second_run_into_the_same_folder_is_one_error(demo, tmp_path, capsys):
    source, target = demo
    out = tmp_path / "aligned"
    assert main(["batch", source, "-r", target, "--output-dir", str(out)]) == 0
    capsys.readouterr()
    assert main(["batch", source, "-r", target, "--output-dir", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "FAILED" not in err[0]
    assert "2 of the outputs exist" in err[0]
    assert "--skip-existing" in err[0] and "--overwrite" in err[0]
    assert main(["batch", source, "-r", target, "--output-dir", str(out),
                 "--skip-existing"]) == 0
