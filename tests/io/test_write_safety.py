# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Writes that another user of a shared folder cannot hijack.

The attacker is a real race: a thread that watches the output folder and, as
soon as a temporary entry of ours appears, replaces it by a link to a file it
controls (a temporary file: a link in its place; a temporary folder: renamed
away, and a folder of its own with a link inside put in its place).  A write
must then either publish our complete data as a regular file, or fail with an
error; it must never write into the attacker's file nor publish a link.
"""

import os
import sys
import threading

import numpy as np
import pytest
from astropy.nddata import CCDData

from astroalign_nd.io.write import atomic_open, atomic_write, write_ccddata

# Only the link planting and the folder's mode are POSIX: the other tests (an input refused
# as the output, long names) run on Windows too.
POSIX = pytest.mark.skipif(os.name == "nt", reason="planting links needs privileges on Windows")


class _Attacker(threading.Thread):
    def __init__(self, folder, bait):
        super().__init__(daemon=True)
        self.folder, self.bait = folder, bait
        self.stop = threading.Event()
        self.swaps = 0

    def run(self):
        n = 0
        while not self.stop.is_set():
            for name in os.listdir(self.folder):
                if "aat-tmp" not in name or name.endswith(".moved"):
                    continue
                path = os.path.join(self.folder, name)
                n += 1
                try:
                    if os.path.isdir(path) and not os.path.islink(path):
                        os.rename(path, f"{path}.{n}.moved")
                        os.mkdir(path)
                        for inner in ("part.fits", "part"):
                            os.symlink(self.bait, os.path.join(path, inner))
                    elif not os.path.islink(path):
                        os.unlink(path)
                        os.symlink(self.bait, path)
                    self.swaps += 1
                except OSError:
                    pass


@POSIX
@pytest.mark.parametrize("how", ["write_ccddata", "atomic_write"])
def test_planted_link_never_followed(tmp_path, how):
    folder = tmp_path / "shared"
    folder.mkdir()
    bait = tmp_path / "attacker.txt"
    bait.write_bytes(b"attacker's file")
    data = np.arange(600 * 600, dtype=np.float32).reshape(600, 600)
    attacker = _Attacker(str(folder), str(bait))
    # Short GIL slices: the attacker thread gets its turns while a frame is written, as a
    # process of another user would on a machine under load (a fixed 10 writes could end
    # with no swap at all in a busy test run).
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    attacker.start()
    outcomes = []
    try:
        for i in range(300):  # until the race has been run a few times
            if i >= 10 and attacker.swaps >= 3:
                break
            out = folder / f"frame{i}.fits"
            try:
                if how == "write_ccddata":
                    write_ccddata(CCDData(data, unit="adu"), out)
                else:
                    with atomic_write(out) as tmp:
                        CCDData(data, unit="adu").write(tmp)
                outcomes.append("written")
            except OSError:
                outcomes.append("refused")
                continue
            assert not out.is_symlink()
            assert np.array_equal(CCDData.read(out).data, data)
    finally:
        attacker.stop.set()
        attacker.join(timeout=10)
        sys.setswitchinterval(interval)
    assert bait.read_bytes() == b"attacker's file"  # never written into
    assert attacker.swaps > 0  # the race was really run
    # A swap is noticed and the write refused, or (through the private folder's descriptor)
    # it does not matter at all: most writes go through.
    assert outcomes.count("written") >= len(outcomes) // 2, outcomes
    assert not any(p.is_symlink() and not p.name.startswith(".") for p in folder.iterdir())


@POSIX
def test_private_folder_mode_and_bounded_name(tmp_path):
    long_name = "x" * 200 + ".fits.gz"  # the temporary name must not grow with it
    seen = {}
    with atomic_write(tmp_path / long_name) as tmp:
        seen["mode"] = os.stat(os.path.dirname(tmp)).st_mode & 0o777
        seen["name"] = os.path.basename(tmp)
        with open(tmp, "wb") as f:
            f.write(b"ok")
    assert seen["mode"] == 0o700
    assert seen["name"] == "part.fits.gz"
    assert (tmp_path / long_name).read_bytes() == b"ok"
    assert os.listdir(tmp_path) == [long_name]


@pytest.mark.skipif(os.name == "nt", reason="a 240-character name passes Windows' 260-character "
                    "path limit (MAX_PATH) wherever long paths are not enabled")
def test_long_output_name_is_written(tmp_path):
    """Names up to the file system's limit (255) work: the temporary name is short."""
    name = "n" * 240 + ".fits"
    write_ccddata(CCDData(np.ones((4, 4), np.float32), unit="adu"), tmp_path / name)
    assert CCDData.read(tmp_path / name).shape == (4, 4)
    assert os.listdir(tmp_path) == [name]


def test_gzip_output_is_compressed(tmp_path):
    path = tmp_path / "f.fits.gz"
    write_ccddata(CCDData(np.ones((16, 16), np.float32), unit="adu"), path)
    assert path.read_bytes()[:2] == b"\x1f\x8b"
    assert CCDData.read(path).shape == (16, 16)


def test_atomic_open_failure_leaves_nothing(tmp_path):
    path = tmp_path / "out.bin"
    with pytest.raises(RuntimeError):
        with atomic_open(path) as f:
            f.write(b"half")
            raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []


def _files(tmp_path):
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((128, 128), n_stars=60, rotation=10.0, seed=3)
    src, dst = tmp_path / "s.fits", tmp_path / "t.fits"
    CCDData(pair.source, unit="adu").write(src)
    CCDData(pair.target, unit="adu").write(dst)
    return src, dst


@pytest.mark.parametrize("which", ["target", "source", "target-via-link"])
def test_register_refuses_an_input_as_output(tmp_path, capsys, which):
    from astroalign_nd.cli import main

    src, dst = _files(tmp_path)
    before = {p: p.read_bytes() for p in (src, dst)}
    out = {"target": dst, "source": src}.get(which)
    if which == "target-via-link":
        (tmp_path / "sub").mkdir()
        out = tmp_path / "sub" / ".." / "t.fits"
    code = main(["register", str(src), str(dst), "-o", str(out), "--overwrite"])
    assert code == 2
    assert "would destroy that input" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in (src, dst)} == before


def test_plot_refuses_an_input(tmp_path):
    pytest.importorskip("matplotlib")
    from astroalign_nd.visualization import save_diagnostic_figure

    src, dst = _files(tmp_path)
    before = src.read_bytes()
    with pytest.raises(ValueError, match="would destroy that input"):
        save_diagnostic_figure(str(src), str(src), str(dst), overwrite=True)
    assert src.read_bytes() == before


def test_atomic_write_path_works_for_another_process(tmp_path):
    """The yielded path is a path: a subprocess (an external tool) can write the file."""
    import subprocess
    import sys

    out = tmp_path / "tool.fits"
    with atomic_write(out) as tmp:
        subprocess.run([sys.executable, "-c",
                        "import sys; open(sys.argv[1], 'wb').write(b'from a tool')", tmp],
                       check=True)
    assert out.read_bytes() == b"from a tool"
    assert os.listdir(tmp_path) == ["tool.fits"]


def test_register_refuses_its_own_image_as_the_plot(tmp_path, capsys):
    """
    ``--plot`` naming an input PNG (a plot's own format, so its ending is
    accepted): refused before any work, the input untouched.
    """
    pytest.importorskip("matplotlib")
    from skimage.io import imsave

    from astroalign_nd.cli import main
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((128, 128), n_stars=60, rotation=10.0, seed=3)
    names = []
    for name, data in (("s.png", pair.source), ("t.png", pair.target)):
        scaled = np.clip(data / np.percentile(data, 99.5) * 255, 0, 255).astype(np.uint8)
        imsave(tmp_path / name, scaled)
        names.append(tmp_path / name)
    src, dst = names
    before = src.read_bytes()
    code = main(["register", str(src), str(dst), "-o", str(tmp_path / "out.fits"),
                 "--plot", str(src), "--overwrite"])
    assert code == 2
    assert "would destroy that input" in capsys.readouterr().err
    assert src.read_bytes() == before
    assert not (tmp_path / "out.fits").exists()


def test_package_writes_never_hand_a_temporary_name_out(tmp_path, monkeypatch, capsys):
    """
    Plots, tables and the batch summary are written through the file the
    package opened (`atomic_open`), not a path to the temporary file: where
    the system cannot name a file through an open folder (macOS, BSD: no
    /proc), a path would go through the private folder's name, which
    another user of a shared folder can rename.
    """
    pytest.importorskip("matplotlib")
    from astropy.table import Table

    from astroalign_nd.io import write as write_module
    from astroalign_nd.io.write import write_table
    from astroalign_nd.visualization import _agg_figure, _save

    class NoPath(write_module._PrivateFolder):
        """A private folder whose temporary file's path cannot be read."""

        @property
        def temp(self):
            raise AssertionError("a temporary path was handed out")

        @temp.setter
        def temp(self, value):
            self.__dict__["_temp"] = value

    if write_module._DIR_FD:  # without descriptors (Windows) the path is all there is
        monkeypatch.setattr(write_module, "_PrivateFolder", NoPath)
    fig = _agg_figure((2, 2))
    fig.add_subplot().plot([0, 1], [1, 0])
    _save(fig, tmp_path / "plot.png", False, 50)
    assert (tmp_path / "plot.png").read_bytes()[:4] == b"\x89PNG"
    table = Table({"x": [1.5, 2.5], "name": ["a", "b"]})
    for name, fmt in (("t.ecsv", "ascii.ecsv"), ("t.csv", "ascii.csv"), ("t.fits", "fits")):
        write_table(table, tmp_path / name, format=fmt)
        back = Table.read(tmp_path / name, format=fmt)
        assert back["x"].tolist() == [1.5, 2.5] and list(back["name"]) == ["a", "b"]
    with pytest.raises(FileExistsError, match="overwrite"):
        write_table(table, tmp_path / "t.csv", format="ascii.csv")
    assert sorted(os.listdir(tmp_path)) == ["plot.png", "t.csv", "t.ecsv", "t.fits"]


def test_write_table_refuses_bad_arguments(tmp_path):
    from astropy.table import Table

    from astroalign_nd.io import write_table

    with pytest.raises(TypeError, match="astropy Table"):
        write_table({"x": [1.0]}, tmp_path / "t.csv", format="ascii.csv")
    for fmt in ("bogus", None, "png"):
        with pytest.raises(ValueError, match="not a Table format"):
            write_table(Table({"x": [1.0]}), tmp_path / "t.csv", format=fmt)
    assert os.listdir(tmp_path) == []
