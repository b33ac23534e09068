# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Build and execute the ``register_and_stack.ipynb`` tutorial.

The notebook is stored with its outputs (the documentation renders it with
``nbsphinx_execute = 'never'``), so rerun this script whenever the tutorial or
the package changes::

    python docs/tutorials/make_register_and_stack.py

It needs nbformat, nbclient and ipykernel (``pip install nbformat nbclient
ipykernel``) besides the package and matplotlib.  The run takes well under a
minute: the frames are small simulated images.
"""

import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
NOTEBOOK = HERE / "register_and_stack.ipynb"

CELLS = [
    ("markdown", """\
# Register and stack simulated frames

This tutorial simulates four exposures of one star field, taken with the camera
turned and pointed a little differently each time, registers three of them onto
the fourth with `astroalign_nd`, and stacks them with `ccdproc.combine`.  Since the
frames are simulated, the true transforms are known and the recovered ones can be
checked against them.

The notebook is stored with its outputs; `docs/tutorials/make_register_and_stack.py`
rebuilds and reruns it."""),

    ("code", """\
import numpy as np
import matplotlib.pyplot as plt
from astropy import units as u
from astropy.nddata import CCDData
from astropy.table import Table
from astropy.visualization import ImageNormalize, ZScaleInterval
import ccdproc

import astroalign_nd
from astroalign_nd import SimilarityTransform
from astroalign_nd.simulate import draw_fluxes, simulate_image

print("astroalign_nd", astroalign_nd.__version__)"""),

    ("markdown", """\
## A star field, observed four times

The field is a list of stars with positions on the sky, in pixels from the field
centre, and fluxes drawn from a power-law luminosity function.  An exposure sees
the field through a `SimilarityTransform` from the sky to the detector: a rotation
of the camera and a pointing offset.  `simulate_image` renders the stars with sky
background, photon noise and read noise, in counts (ADU, with a gain of 1)."""),

    ("code", """\
shape = (384, 384)
rng = np.random.default_rng(42)
n_field = 600
sky_x, sky_y = rng.uniform(-300.0, 300.0, size=(2, n_field))
flux = draw_fluxes(n_field, flux_range=(300.0, 3e5), seed=43)

# (rotation in degrees, pointing offset in pixels) of each exposure
pointings = [(0.0, (0.0, 0.0)), (8.0, (12.5, -7.0)), (-15.0, (-9.0, 14.0)),
             (25.0, (5.0, 10.5))]
centre = (np.array(shape[::-1]) - 1.0) / 2.0
to_detector = [SimilarityTransform(rotation=rot,
                                   translation_x=centre[0] + dx,
                                   translation_y=centre[1] + dy)
               for rot, (dx, dy) in pointings]

read_noise = 5.0
frames = []
for i, t in enumerate(to_detector):
    data = simulate_image(shape, *t(sky_x, sky_y), flux, fwhm=3.0, background=150.0,
                          read_noise=read_noise, seed=100 + i)
    frame = CCDData(data, unit="adu", meta={"OBJECT": "SIMFIELD", "FRAME": i})
    # Photon noise and read noise, as ccdproc.create_deviation would give.
    frame = ccdproc.create_deviation(frame, gain=1.0 * u.electron / u.adu,
                                     readnoise=read_noise * u.electron,
                                     disregard_nan=True)
    frames.append(frame)

reference, others = frames[0], frames[1:]
print(len(frames), "frames of", reference.shape, "pixels, unit", reference.unit,
      "with", type(reference.uncertainty).__name__)"""),

    ("markdown", """\
## Register onto the reference

`Reference` prepares the reference frame once (its stars and triangles are kept),
and `register` resamples each frame onto the reference's pixel grid.  Each result
is a new `CCDData` with the mask, the propagated uncertainty and the registration
recorded in its header."""),

    ("code", """\
ref = astroalign_nd.Reference(reference)
aligned = [astroalign_nd.register(frame, ref) for frame in others]

a = aligned[0]
print(type(a).__name__, a.shape, a.unit, type(a.uncertainty).__name__)
print("masked pixels (outside the frame's footprint):", f"{a.mask.mean():.1%}")
print()
print(repr(a.meta[-10:]))"""),

    ("markdown", """\
## How good are the transforms?

The header's `AATNMAT`, `AATRMS` and `AATLFA` keywords give the number of matched
stars, the RMS residual of the fit and the log10 false-alarm probability (see
[Can I trust the transform?](../trust.rst)).  The transform itself is
rebuilt from the header with `transform_from_header`.

The true frame-to-reference transform is the reference's sky-to-detector
transform composed with the inverse of the frame's.  The last column is the
largest distance, over the frame's corners, between where the recovered and the
true transforms put a pixel."""),

    ("code", """\
ny, nx = shape
corner_x = np.array([0.0, nx - 1.0, 0.0, nx - 1.0])
corner_y = np.array([0.0, 0.0, ny - 1.0, ny - 1.0])

rows = []
for i, a in enumerate(aligned, start=1):
    found = astroalign_nd.transform_from_header(a.meta)
    truth = to_detector[i].inverse | to_detector[0]
    error = np.hypot(*np.subtract(found(corner_x, corner_y), truth(corner_x, corner_y)))
    rows.append((i, a.meta["AATNMAT"], a.meta["AATRMS"], a.meta["AATLFA"],
                 found.rotation_deg, pointings[0][0] - pointings[i][0], error.max()))

quality = Table(rows=rows, names=("frame", "matched", "rms_px", "log10_fa",
                                  "rotation_deg", "true_rotation_deg", "max_error_px"))
for name in ("rms_px", "rotation_deg", "max_error_px"):
    quality[name].format = ".3f"
quality["log10_fa"].format = ".1f"
quality"""),

    ("markdown", """\
## Stack with ccdproc

`ccdproc.combine` takes the registered frames as they are.  Masked pixels (outside
a frame's footprint) are left out of the combination at that pixel.

Sigma clipping needs one precaution: ccdproc clips the raw data arrays, where the
masked pixels of the registered frames hold NaN (`register`'s `fill_value`), so
give it NaN-aware functions.  With its defaults (`numpy.ma.mean` and
`numpy.ma.std`), one NaN would reject every frame at that pixel.  astropy then
warns that it clipped the NaN values, which is what we want here."""),

    ("code", """\
import warnings
from astropy.utils.exceptions import AstropyUserWarning

with warnings.catch_warnings():
    warnings.simplefilter("ignore", AstropyUserWarning)  # "... NaNs ... clipped"
    stack = ccdproc.combine([reference, *aligned], method="average",
                            sigma_clip=True, sigma_clip_low_thresh=5,
                            sigma_clip_high_thresh=5, sigma_clip_func=np.nanmedian,
                            sigma_clip_dev_func=np.nanstd)


def pixel_noise(image):
    \"\"\"Robust standard deviation of neighbouring-pixel differences (sky noise).\"\"\"
    d = np.diff(np.asarray(image, float)[100:284, 100:284], axis=1)
    return 1.4826 * np.nanmedian(np.abs(d - np.nanmedian(d))) / np.sqrt(2)


print(f"sky noise of the reference: {pixel_noise(reference.data):.2f} adu")
print(f"sky noise of the stack:     {pixel_noise(stack.data):.2f} adu")
print("pixels masked in the stack:", int(stack.mask.sum()))"""),

    ("markdown", """\
The pixel-to-pixel noise drops by more than the factor of two expected from
averaging four independent frames: resampling smooths the registered frames, which
lowers the noise of each pixel but correlates neighbouring pixels.  The per-pixel
uncertainties of the registered frames are right, but not independent (see [A
ccdproc workflow](../ccdproc.rst)).

## The images

The source frame (frame 1), the target (the reference), the source registered
onto the target's grid (masked pixels in blue), and the stack of the four frames."""),

    ("code", """\
norm = ImageNormalize(reference.data, interval=ZScaleInterval())
cmap = plt.get_cmap("gray_r").with_extremes(bad="#9ecae1")
panels = [("source (frame 1)", others[0].data),
          ("target (reference)", reference.data),
          ("registered source", np.ma.masked_array(aligned[0].data, aligned[0].mask)),
          ("stack of 4 frames", np.ma.masked_array(stack.data, stack.mask))]
fig, axes = plt.subplots(1, 4, figsize=(12, 3.4), sharex=True, sharey=True,
                         layout="constrained")
for ax, (title, image) in zip(axes, panels):
    ax.imshow(image, origin="lower", cmap=cmap, norm=norm, interpolation="nearest")
    ax.set_title(title)
    ax.set_xlabel("x [px]")
axes[0].set_ylabel("y [px]")
plt.show()"""),
]


def build():
    import nbformat
    from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

    nb = new_notebook()
    nb.metadata["kernelspec"] = {"display_name": "Python 3", "language": "python",
                                 "name": "python3"}
    nb.metadata["language_info"] = {"name": "python"}
    for kind, source in CELLS:
        nb.cells.append(new_code_cell(source) if kind == "code" else new_markdown_cell(source))
    # Stable cell ids, so that rebuilding does not change the file needlessly.
    for i, cell in enumerate(nb.cells):
        cell["id"] = f"cell-{i:02d}"
    nbformat.validate(nb)
    return nb


# IPython configuration of the kernel that runs the notebook: the figure is stored as
# a JPEG, a fraction of the size of a PNG of noisy images.  (Run interactively, the
# notebook gives the usual PNG.)
_KERNEL_CONFIG = """\
c.InlineBackend.figure_formats = {"jpeg"}
c.InlineBackend.print_figure_kwargs = {"bbox_inches": "tight",
                                       "pil_kwargs": {"quality": 85}}
"""

# Messages of the build environment rather than of the tutorial: tqdm (imported by
# photutils) warns when ipywidgets is not installed.
_NOISE = ("TqdmWarning", "from .autonotebook import tqdm")


def execute(nb):
    from nbclient import NotebookClient

    with tempfile.TemporaryDirectory() as ipython_dir:
        profile = Path(ipython_dir) / "profile_default"
        profile.mkdir()
        (profile / "ipython_kernel_config.py").write_text(_KERNEL_CONFIG)
        env = dict(os.environ, IPYTHONDIR=ipython_dir)
        env.pop("MPLBACKEND", None)
        client = NotebookClient(nb, timeout=600, kernel_name="python3",
                                resources={"metadata": {"path": str(HERE)}})
        client.execute(env=env)
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs = [o for o in cell.outputs
                            if not (o.get("name") == "stderr"
                                    and any(n in o.get("text", "") for n in _NOISE))]
    return nb


def main():
    import nbformat

    nb = execute(build())
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        for output in cell.get("outputs", []):
            if output.get("name") == "stderr":
                print("warning: a cell wrote to stderr:\n" + output["text"], file=sys.stderr)
    nbformat.write(nb, NOTEBOOK)
    print(f"wrote {NOTEBOOK}")


if __name__ == "__main__":
    main()
