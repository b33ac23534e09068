# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""register_batch: unique outputs, atomic writes, resume, the union canvas, workers."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData
from astropy.table import Table
from astropy.wcs import WCS

from astroalign_nd import AstroalignWarning, Reference, register_batch
from astroalign_nd.batch import plan_outputs, union_canvas
from astroalign_nd.io.write import atomic_write, write_ccddata
from astroalign_nd.simulate import draw_fluxes, simulate_image
from astroalign_nd.transforms import TranslationTransform

SHAPE = (192, 192)
WORKTREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _sky(n=500, extent=320, seed=3):
    """One star field, in sky pixels ``0..extent``; frames are cut from it."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(0, extent, n), rng.uniform(0, extent, n),
            draw_fluxes(n, flux_range=(1e3, 2e5), seed=seed + 1))


def _frame(sky, corner, seed, shape=SHAPE):
    """The frame whose pixel (0, 0) is at sky position ``corner``: a pure shift."""
    x, y, f = sky
    return simulate_image(shape, x - corner[0], y - corner[1], f, seed=seed)


def _write(path, data, **header):
    hdr = fits.Header(header)
    hdr["BUNIT"] = "adu"
    fits.PrimaryHDU(np.asarray(data, np.float32), header=hdr).writeto(path)
    return str(path)


@pytest.fixture(scope="module")
def sky():
    return _sky()


@pytest.fixture
def night(tmp_path, sky):
    """A reference and three shifted frames on disk, with their true shifts."""
    ref_corner = (60.0, 60.0)
    corners = [(72.3, 51.6), (49.4, 68.2), (61.7, 57.9)]
    ref = _write(tmp_path / "ref.fits", _frame(sky, ref_corner, 100))
    paths = [_write(tmp_path / f"f{k}.fits", _frame(sky, c, 200 + k), OBJECT=f"f{k}")
             for k, c in enumerate(corners)]
    # source pixel p sits at sky p + corner, i.e. at reference pixel p + corner - ref_corner
    shifts = [(c[0] - ref_corner[0], c[1] - ref_corner[1]) for c in corners]
    return ref, paths, shifts


def _shift_error(transform, shift):
    m = transform.matrix
    return max(abs(m[0, 2] - shift[0]), abs(m[1, 2] - shift[1]),
               abs(m[0, 0] - 1), abs(m[1, 1] - 1), abs(m[0, 1]), abs(m[1, 0]))


# -- output names ----------------------------------------------------------------------------


def test_plan_outputs_unique_and_deterministic(tmp_path):
    srcs = ["in/a.fits", "in2/a.fits", "in/a_1.fits", "in/a.fit", "in/A.FITS", "in/a_2.fits"]
    paths, renamed = plan_outputs(srcs, str(tmp_path), "_aligned")
    names = [os.path.basename(p) for p in paths]
    assert len({n.casefold() for n in names}) == len(names)
    # the first keeps its natural name; a natural name of a later frame is never taken
    assert names[0] == "a_aligned.fits"
    assert names[2] == "a_1_aligned.fits" and names[5] == "a_2_aligned.fits"
    assert [i for i, _, _ in renamed] == [1, 3, 4]
    assert plan_outputs(srcs, str(tmp_path), "_aligned") == (paths, renamed)
    # an output never lands on an input file of the same folder
    src = tmp_path / "b.fits"
    paths, renamed = plan_outputs([str(src), str(tmp_path / "b_aligned.fits")], str(tmp_path))
    assert os.path.basename(paths[0]) != "b_aligned.fits" and renamed


def test_colliding_names_lose_nothing(tmp_path, sky):
    (tmp_path / "in").mkdir()
    (tmp_path / "in2").mkdir()
    ref = _write(tmp_path / "ref.fits", _frame(sky, (60, 60), 1))
    srcs = []
    for k, rel in enumerate(["in/a.fits", "in2/a.fits", "in/a_1.fits", "in/a.fit"]):
        srcs.append(_write(tmp_path / rel, _frame(sky, (60 + 3 * k + 0.4, 58.6), 10 + k),
                           OBJECT=f"id{k}"))
    out = tmp_path / "out"
    out.mkdir()
    with pytest.warns(AstroalignWarning, match="renamed"):
        result = register_batch(srcs, ref, output_dir=out, overwrite=True)
    assert len(result.succeeded) == 4, result.summary()
    assert result.summary().startswith("4 of 4 frames registered")
    outputs = [f.output for f in result.frames]
    assert len(set(outputs)) == 4 and len(os.listdir(out)) == 4
    for k, f in enumerate(result.frames):
        # each file holds its own frame: the source header and the right shift
        ccd = CCDData.read(f.output)
        assert ccd.meta["OBJECT"] == f"id{k}"
        assert _shift_error(f.transform, (3 * k + 0.4, -1.4)) < 0.05
    # names shown are unambiguous
    assert len({f.name for f in result.frames}) == 4


# -- atomic writes ---------------------------------------------------------------------------


def test_failed_write_keeps_old_output(tmp_path, night, monkeypatch):
    ref, paths, _ = night
    out = tmp_path / "out"
    first = register_batch(paths[:1], ref, output_dir=out)
    target = first.frames[0].output
    before = Path(target).read_bytes()

    def broken_write(self, file, *args, **kwargs):
        # half a file, then the disk "fills up" (the package writes to an open file)
        file.write(b"SIMPLE  =                    T" + b" " * 1000)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(CCDData, "write", broken_write)
    # a full disk stops the batch with one error (the next frames would fail the same way)
    with pytest.raises(OSError, match="the disk is full.*skip_existing") as info:
        register_batch(paths[:1], ref, output_dir=out, overwrite=True)
    assert info.value.errno == 28
    assert Path(target).read_bytes() == before  # the old output is intact
    assert sorted(os.listdir(out)) == [os.path.basename(target)]  # no temporary left over
    # without an old output: nothing under the final name
    with pytest.raises(OSError, match="the disk is full"):
        register_batch(paths[1:2], ref, output_dir=out)
    assert sorted(os.listdir(out)) == [os.path.basename(target)]


def test_killed_during_write_leaves_no_partial_file(tmp_path):
    """A process killed in the middle of a write: the final name keeps the old file."""
    final = tmp_path / "out.fits"
    CCDData(np.zeros((8, 8), np.float32), unit="adu").write(final)
    old = final.read_bytes()
    script = textwrap.dedent(f"""
        import sys, time
        import numpy as np
        from astropy.io import fits
        from astropy.nddata import CCDData
        from astroalign_nd.io.write import write_ccddata

        real = fits.HDUList.writeto
        def slow_writeto(self, fh, *args, **kwargs):  # the package writes to an open file
            fh.write(b"SIMPLE  =                    T" + b" " * 2850)
            fh.flush()
            print("writing", flush=True)
            time.sleep(60)  # killed here
            real(self, fh, *args, **kwargs)
        fits.HDUList.writeto = slow_writeto
        write_ccddata(CCDData(np.ones((64, 64), np.float32), unit="adu"), {str(final)!r},
                      overwrite=True)
    """)
    env = dict(os.environ, PYTHONPATH=WORKTREE + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, env=env)
    try:
        assert proc.stdout.readline().strip() == b"writing"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        proc.stdout.close()
    assert final.read_bytes() == old
    leftovers = [p for p in os.listdir(tmp_path) if p != "out.fits"]
    # only a hidden private folder (which globs like *.fits do not match) may remain
    assert leftovers and all(p.startswith(".aat-tmp-") for p in leftovers)


def test_atomic_write_refuses_existing(tmp_path):
    path = tmp_path / "x.fits"
    write_ccddata(CCDData(np.zeros((4, 4)), unit="adu"), path)
    with pytest.raises(FileExistsError, match="overwrite"):
        write_ccddata(CCDData(np.ones((4, 4)), unit="adu"), path)
    assert np.all(CCDData.read(path).data == 0)
    with pytest.raises(RuntimeError):
        with atomic_write(path, overwrite=True) as tmp:
            Path(tmp).write_text("partial")
            raise RuntimeError("stop")
    assert np.all(CCDData.read(path).data == 0)
    assert os.listdir(tmp_path) == ["x.fits"]


# -- resume ----------------------------------------------------------------------------------


def test_resume_skips_complete_outputs(tmp_path, night):
    ref, paths, shifts = night
    out = tmp_path / "out"
    first = register_batch(paths[:2], ref, output_dir=out)
    assert [f.status for f in first.frames] == ["registered", "registered"]
    mtimes = [os.stat(f.output).st_mtime_ns for f in first.frames]

    # without skip_existing, existing outputs fail (and say how to resume)
    again = register_batch(paths, ref, output_dir=out)
    assert [f.status for f in again.frames] == ["failed", "failed", "registered"]
    assert "skip_existing" in again.frames[0].error
    os.remove(again.frames[2].output)

    resumed = register_batch(paths, ref, output_dir=out, skip_existing=True)
    assert [f.status for f in resumed.frames] == ["skipped", "skipped", "registered"]
    assert [os.stat(f.output).st_mtime_ns for f in resumed.frames[:2]] == mtimes
    assert not resumed.failed
    assert "1 of 3 frames registered, 2 skipped" in resumed.summary()
    for f, s in zip(resumed.frames, shifts):  # skipped frames report what their file holds
        assert _shift_error(f.transform, s) < 0.05
        assert f.quality["n_matches"] >= 10

    # an incomplete file under the final name (e.g. from another tool) is not "done"
    victim = resumed.frames[1].output
    data = Path(victim).read_bytes()
    with open(victim, "wb") as fh:
        fh.write(data[: len(data) // 2])
    res = register_batch(paths, ref, output_dir=out, skip_existing=True)
    assert [f.status for f in res.frames] == ["skipped", "failed", "skipped"]
    assert "incomplete" in res.frames[1].error
    res = register_batch(paths, ref, output_dir=out, skip_existing=True, overwrite=True)
    assert [f.status for f in res.frames] == ["skipped", "registered", "skipped"]
    assert CCDData.read(victim).shape == SHAPE


def test_batch_argument_checks(night, tmp_path):
    ref, paths, _ = night
    with pytest.raises(ValueError, match="canvas"):
        register_batch(paths, ref, canvas="mosaic")
    with pytest.raises(ValueError, match="output_dir"):
        register_batch(paths, ref, skip_existing=True)
    with pytest.raises(TypeError, match="fwhmm"):  # before any frame is processed
        register_batch(paths, ref, fwhmm=3)
    with pytest.raises(TypeError, match="single path"):
        register_batch(paths[0], ref)
    with pytest.raises(ValueError, match="workers"):
        register_batch(paths, ref, workers=-1)


# -- summary table and streaming -------------------------------------------------------------


def test_callback_streams_and_table(tmp_path, night):
    ref, paths, _ = night
    seen = []
    srcs = [paths[0], str(tmp_path / "missing.fits"), paths[1]]
    result = register_batch(srcs, ref, output_dir=tmp_path / "out",
                            callback=lambda f: seen.append((f.name, f.status,
                                                            os.path.exists(f.output or ""))))
    # each frame is reported as it is done, with its file already complete
    assert seen == [("f0.fits", "registered", True), ("missing.fits", "failed", False),
                    ("f1.fits", "registered", True)]
    path = tmp_path / "night.ecsv"
    result.to_table().write(path)
    t = Table.read(path)
    assert list(t.colnames) == ["name", "status", "ok", "n_matches", "rms",
                                "log10_false_alarm", "shift_x", "shift_y", "rotation", "scale",
                                "seconds", "error", "output", "source"]
    assert np.isnan(t["shift_x"][1]) and abs(t["scale"][0] - 1) < 0.01
    assert list(t["status"]) == ["registered", "failed", "registered"]
    assert t["n_matches"][0] >= 10 and t["rms"][0] < 1 and t["log10_false_alarm"][0] < -6
    assert "not found" in t["error"][1]
    assert np.all(t["seconds"] > 0)


# -- detection options -----------------------------------------------------------------------


def test_reference_detection_options_reach_the_frames(night, monkeypatch):
    ref, paths, shifts = night
    import astroalign_nd.detection.daofind as detection

    calls = []
    real = detection._detect  # the detection of checked options (a config)

    def spy(image, mask, n_sources, config, nsigma, *cache):
        calls.append(config.fwhm)
        return real(image, mask, n_sources, config, nsigma, *cache)

    monkeypatch.setattr(detection, "_detect", spy)
    result = register_batch(paths, Reference(ref, fwhm=3.2))
    assert not result.failed
    assert len(calls) >= 4 and all(c == 3.2 for c in calls)  # reference and every frame
    calls.clear()
    # options given to register_batch win over the Reference's
    register_batch(paths[:1], Reference(ref, fwhm=3.2), fwhm=2.9)
    assert calls[-1] == 2.9


# -- the union canvas ------------------------------------------------------------------------


def test_union_canvas_geometry():
    shapes = [(100, 100), (100, 100)]
    ts = [TranslationTransform(translation_x=10.4, translation_y=-5.6),
          TranslationTransform(translation_x=-7.6, translation_y=3.4)]
    shape, offset = union_canvas(ts, shapes, (100, 100), margin=0.0)
    # pixel centres covered: x from -7.6 to 99 + 10.4, y from -5.6 to 99 + 3.4
    assert offset == (-7, -5)
    assert shape == (102 - (-5) + 1, 109 - (-7) + 1)


def test_union_canvas_stacks_dither_without_loss(tmp_path, sky):
    """A 4-point box dither around the reference stacks with no masked pixel at all."""
    from ccdproc import combine

    ref_corner = (70.0, 70.0)
    wcs = WCS(naxis=2)
    wcs.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    wcs.wcs.crpix = [96.5, 96.5]
    wcs.wcs.crval = [150.0, 2.0]
    wcs.wcs.cdelt = [-1e-4, 1e-4]
    ref_hdr = wcs.to_header()
    ref_hdr["BUNIT"] = "adu"
    ref = str(tmp_path / "ref.fits")
    fits.PrimaryHDU(_frame(sky, ref_corner, 1), header=ref_hdr).writeto(ref)
    d = (21.4, 15.4)
    corners = [(ref_corner[0] + sx * d[0], ref_corner[1] + sy * d[1])
               for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    paths = [_write(tmp_path / f"d{k}.fits", _frame(sky, c, 20 + k))
             for k, c in enumerate(corners)]
    result = register_batch(paths, ref, output_dir=tmp_path / "out", canvas="union")
    assert not result.failed, result.summary()
    ny, nx = SHAPE
    # the canvas holds every frame: 2 * dither larger than one frame, less the
    # bilinear edge pixel lost on each side
    assert result.canvas_offset == (-21, -15)
    assert result.canvas_shape == (ny + 2 * 15, nx + 2 * 21)
    ccds = [CCDData.read(f.output) for f in result.frames]
    for ccd, c, f in zip(ccds, corners, result.frames):
        assert ccd.shape == result.canvas_shape
        # transform: source -> canvas = shift by corner - ref_corner - canvas offset
        exp = (c[0] - ref_corner[0] + 21, c[1] - ref_corner[1] + 15)
        assert _shift_error(f.transform, exp) < 0.05
        # footprint is the mask: about one frame's worth of valid pixels
        assert abs((~ccd.mask).sum() - (ny - 1) * (nx - 1)) < 2 * (nx + ny)
        # the WCS goes along: a canvas pixel has the sky position of its reference pixel
        ra, dec = ccd.wcs.pixel_to_world_values(10.0, 20.0)
        ra0, dec0 = wcs.pixel_to_world_values(10.0 - 21, 20.0 - 15)
        assert abs(ra - ra0) < 1e-9 and abs(dec - dec0) < 1e-9
    stack = combine(ccds, method="average")
    assert stack.shape == result.canvas_shape
    assert not np.any(stack.mask) and np.all(np.isfinite(stack.data))
    # the same frames on the reference's grid lose their outer parts
    lost = register_batch(paths, ref)
    assert all(f.ccd.mask.mean() > 0.15 for f in lost.frames)

    # resuming a union run keeps the outputs (same canvas)
    again = register_batch(paths, ref, output_dir=tmp_path / "out", canvas="union",
                           skip_existing=True)
    assert [f.status for f in again.frames] == ["skipped"] * 4
    assert again.canvas_shape == result.canvas_shape
    for f, g in zip(result.frames, again.frames):
        assert np.allclose(f.transform.matrix, g.transform.matrix, atol=1e-9)
    # ...and refuses to mix canvases when the set of frames changes
    extra = _write(tmp_path / "d9.fits", _frame(sky, (ref_corner[0] + 40.4, 70.0), 99))
    mixed = register_batch(paths + [extra], ref, output_dir=tmp_path / "out", canvas="union",
                           skip_existing=True)
    assert all("another canvas" in f.error for f in mixed.frames[:4])


# -- parallel --------------------------------------------------------------------------------


def test_local_workers_match_sequential(tmp_path, night):
    ref, paths, shifts = night
    seq = register_batch(paths, ref, output_dir=tmp_path / "a")
    par = register_batch(paths, ref, output_dir=tmp_path / "b", workers=2)
    assert [f.status for f in par.frames] == ["registered"] * 3
    for f, g, s in zip(seq.frames, par.frames, shifts):
        assert f.name == g.name
        assert np.array_equal(f.transform.matrix, g.transform.matrix)
        assert np.array_equal(CCDData.read(f.output).data, CCDData.read(g.output).data,
                              equal_nan=True)
        assert _shift_error(g.transform, s) < 0.05


def test_in_memory_frames_return_ccds(night):
    ref, paths, _ = night
    frames = [CCDData.read(p) for p in paths[:2]]
    result = register_batch(frames, ref)
    assert [f.name for f in result.frames] == ["frame0", "frame1"]
    assert all(f.ccd is not None and f.output is None for f in result.frames)


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
def test_written_files_have_normal_permissions(tmp_path):
    path = tmp_path / "p.fits"
    write_ccddata(CCDData(np.zeros((4, 4)), unit="adu"), path)
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    assert (path.stat().st_mode & 0o777) == (plain.stat().st_mode & 0o777)


def test_write_ccddata_gzip(tmp_path):
    path = tmp_path / "g.fits.gz"
    write_ccddata(CCDData(np.arange(16.0).reshape(4, 4), unit="adu"), path)
    assert path.read_bytes()[:2] == b"\x1f\x8b"  # compressed, as the name says
    assert CCDData.read(path).data[3, 3] == 15


def test_union_canvas_refuses_absurd_size(night, monkeypatch):
    import astroalign_nd.batch.canvas as batch

    ref, paths, _ = night
    monkeypatch.setattr(batch, "_MAX_CANVAS_PIXELS", 200 * 200)
    with pytest.raises(ValueError, match="union canvas would be .*farthest is f0.fits"):
        register_batch(paths, ref, canvas="union")


HATP32 = (os.path.join(os.path.dirname(WORKTREE), "shared", "data", "real", "pairs",
                       "exotic_hatp32_microobservatory"))


@pytest.mark.skipif(not os.path.isdir(HATP32), reason="real test images not available")
def test_union_canvas_keeps_the_drifting_hatp32_night(tmp_path):
    """The HAT-P-32 night drifts by 275 px: on the reference's grid the last frame loses
    about 44% of its pixels, on the union canvas none."""
    paths = sorted(os.path.join(HATP32, p) for p in os.listdir(HATP32))
    on_ref = register_batch(paths, paths[0])
    assert not on_ref.failed, on_ref.summary()
    assert on_ref.frames[-1].ccd.mask.mean() > 0.35
    result = register_batch(paths, paths[0], output_dir=tmp_path, canvas="union")
    assert not result.failed, result.summary()
    ny, nx = CCDData.read(paths[0], unit="adu").shape
    cy, cx = result.canvas_shape
    assert cx > nx + 250 and cy > ny + 50
    for f in result.frames:
        ccd = CCDData.read(f.output)
        # every frame keeps all its pixels but a 1-px bilinear edge (and its hot pixels)
        assert (~ccd.mask).sum() > 0.98 * nx * ny


# -- collections, pairs and generators -------------------------------------------------------


def test_generator_outputs_are_named_as_frames_arrive(tmp_path, night):
    """A generator cannot be looked ahead: each frame's name is fixed when it arrives,
    never reusing one already taken, and the same sequence gives the same names."""
    ref, paths, shifts = night
    (tmp_path / "other").mkdir()
    twin = _write(tmp_path / "other" / "f0.fits", fits.getdata(paths[0]), OBJECT="twin")
    order = [paths[0], twin, paths[1], paths[0]]
    out = tmp_path / "out"

    def frames():
        yield from order

    with pytest.warns(AstroalignWarning, match="renamed") as record:
        result = register_batch(frames(), ref, output_dir=out)
    assert len(record) == 2  # one warning per renamed frame, as it arrives
    assert [f.name for f in result.frames] == ["f0.fits", "f0.fits#2", "f1.fits", "f0.fits#3"]
    assert [os.path.basename(f.output) for f in result.frames] == [
        "f0_aligned.fits", "f0_2_aligned.fits", "f1_aligned.fits", "f0_3_aligned.fits"]
    assert [f.source for f in result.frames] == order
    for f, obj, shift in zip(result.frames, ["f0", "twin", "f1", "f0"],
                             [shifts[0], shifts[0], shifts[1], shifts[0]]):
        assert CCDData.read(f.output).meta["OBJECT"] == obj
        assert _shift_error(f.transform, shift) < 0.05
    # resumed from a new generator of the same frames: the same names, all found again
    with pytest.warns(AstroalignWarning, match="renamed"):
        again = register_batch(frames(), ref, output_dir=out, skip_existing=True)
    assert [f.status for f in again.frames] == ["skipped"] * 4
    assert [f.output for f in again.frames] == [f.output for f in result.frames]


def test_generator_never_writes_onto_an_input_it_has_seen(tmp_path, night):
    ref, paths, _ = night
    folder = os.path.dirname(paths[2])
    # an input whose name is the natural output of a later frame, in the output folder
    decoy = _write(os.path.join(folder, "f2_aligned.fits"), fits.getdata(paths[2]),
                   OBJECT="decoy")
    before = Path(decoy).read_bytes()
    with pytest.warns(AstroalignWarning, match="f2_aligned.fits is taken"):
        result = register_batch((p for p in [decoy, paths[2]]), ref, output_dir=folder,
                                overwrite=True)
    assert not result.failed, result.summary()
    assert [os.path.basename(f.output) for f in result.frames] == [
        "f2_aligned_aligned.fits", "f2_2_aligned.fits"]
    assert Path(decoy).read_bytes() == before
    # nor onto the target
    with pytest.warns(AstroalignWarning, match="renamed"):
        result = register_batch(iter([paths[0]]), ref, output_dir=os.path.dirname(ref),
                                suffix="", overwrite=True)
    assert os.path.basename(result.frames[0].output) == "f0_2.fits"


def test_generator_in_workers_and_on_a_union_canvas(night):
    ref, paths, shifts = night

    def frames():
        for p in paths:
            yield CCDData.read(p)

    par = register_batch(frames(), ref, workers=2)
    assert [f.name for f in par.frames] == ["frame0", "frame1", "frame2"]
    for f, s in zip(par.frames, shifts):
        assert f.status == "registered" and _shift_error(f.transform, s) < 0.05
    # two passes: the generator's frames are collected first (documented)
    union = register_batch(frames(), ref, canvas="union")
    listed = register_batch(list(frames()), ref, canvas="union")
    assert union.canvas_shape == listed.canvas_shape != SHAPE
    assert union.canvas_offset == listed.canvas_offset
    for f, g in zip(union.frames, listed.frames):
        assert np.array_equal(f.ccd.data, g.ccd.data, equal_nan=True)


def test_generator_on_dask_is_fed_as_workers_free_up(night):
    distributed = pytest.importorskip("dask.distributed")
    ref, paths, shifts = night
    taken = []

    def frames():
        for k, p in enumerate(paths * 3):
            taken.append(k)
            yield CCDData.read(p), f"n{k}.fits"  # (frame, file name) pairs

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:  # any free port
        with distributed.Client(cluster) as client:
            seen = []
            result = register_batch(frames(), ref, client=client,
                                    callback=lambda f: seen.append(len(taken)))
    assert [f.name for f in result.frames] == [f"n{k}.fits" for k in range(9)]
    assert not result.failed, result.summary()
    # when the first frame was done, the generator had not been run to its end
    assert seen[0] <= 3
    for k, f in enumerate(result.frames):
        assert _shift_error(f.transform, shifts[k % 3]) < 0.05


def test_pairs_collections_and_plan_outputs(tmp_path, night):
    ccdproc = pytest.importorskip("ccdproc")
    ref, paths, _ = night
    frames = [(CCDData.read(p), f"raw/{os.path.basename(p)}") for p in paths]
    result = register_batch(frames, ref, output_dir=tmp_path / "out")
    assert [f.name for f in result.frames] == ["f0.fits", "f1.fits", "f2.fits"]
    assert sorted(os.listdir(tmp_path / "out")) == [
        "f0_aligned.fits", "f1_aligned.fits", "f2_aligned.fits"]
    assert all(f.source is None for f in result.frames)  # in memory: no input path
    # plan_outputs takes what register_batch takes: pairs and collections too
    ifc = ccdproc.ImageFileCollection(os.path.dirname(ref), glob_include="f*.fits")
    planned, renamed = plan_outputs(ifc, str(tmp_path / "out"))
    assert [os.path.basename(p) for p in planned] == [
        "f0_aligned.fits", "f1_aligned.fits", "f2_aligned.fits"]
    assert not renamed
    assert plan_outputs(frames, str(tmp_path / "out"))[0] == planned


def test_add_keyword_false_in_a_batch(tmp_path, night):
    ref, paths, _ = night
    result = register_batch(paths[:1], ref, output_dir=tmp_path, add_keyword=False)
    header = fits.getheader(result.frames[0].output)
    assert header["OBJECT"] == "f0"
    assert not any(k.startswith("AA") for k in header)
    with pytest.raises(ValueError, match="add_keyword=False"):
        register_batch(paths[:1], ref, output_dir=tmp_path, add_keyword=False,
                       skip_existing=True)


def test_valid_margin_follows_the_resampler_order_names():
    """One check (the resampling config's): names or integers, as apply_transform accepts them."""
    from astroalign_nd.batch.canvas import _valid_margin
    from astroalign_nd.resample import ResampleConfig

    assert [_valid_margin(ResampleConfig(order=o))
            for o in ("nearest-neighbor", 1, "biquadratic", 3)] == [-0.5, 0.0, 0.5, 1.0]
    assert _valid_margin(ResampleConfig(method="exact")) == -0.5
    for bad in ("spline", "BiCubic", 4, True):
        with pytest.raises(ValueError, match="order must be one of"):
            ResampleConfig(order=bad)
