# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``demo`` command: a simulated pair registered and compared with the truth."""

import os
from .errors import _CLIError
from .options import _check_output_dir, _check_writable, _command_parser, _describe

__all__ = []

HELP = "simulate a pair of star fields, register them and compare with the truth"

#: The demo's pair (`~astroalign_nd.simulate.simulate_pair`'s arguments); its help says so.
DEMO_PAIR = dict(shape=(512, 512), n_stars=300, rotation=17.0, scale=1.05,
                 translation=(12.3, -7.7))

#: Header keyword of the demo's files: a later demo replaces them.
_DEMO_KEY = "AADEMO"


def demo_description():
    """The demo's ``--help`` text, from `DEMO_PAIR`."""
    p = DEMO_PAIR
    ny, nx = p["shape"]
    dx, dy = p["translation"]
    return (f"Simulate a {nx}x{ny} star field ({p['n_stars']} stars) and a second view of it "
            f"related by a known similarity transform: rotated by {p['rotation']:g} deg and "
            f"scaled by {p['scale']:g} about the frame centre, the centre shifted by "
            f"({dx:g}, {dy:g}) px (the transform printed is the same one, written about pixel "
            "(0, 0), hence its larger translation). Write DIR/source.fits and "
            "DIR/target.fits, register the source onto the target, write DIR/aligned.fits "
            "and report the error of the recovered transform. Running the demo again "
            "replaces the files an earlier demo wrote (other files under those names only "
            "with --overwrite).")


def add_parser(sub):
    """Add the ``demo`` subcommand to the subparsers ``sub``."""
    p = _command_parser(sub, "demo", _cmd_demo, HELP, demo_description())
    p.add_argument("--output-dir", required=True, metavar="DIR",
                   help="folder for source.fits, target.fits and aligned.fits "
                   "(created if needed)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing files that an earlier demo did not write")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    return p


def _cmd_demo(args):
    import astropy.units as u
    import numpy as np
    from astropy.io import fits
    from astropy.nddata import CCDData

    import astroalign_nd
    from astroalign_nd.io.write import write_ccddata
    from astroalign_nd.simulate import simulate_pair

    if args.seed < 0:
        raise _CLIError(f"--seed must be an integer >= 0; got {args.seed}.")
    out_dir = args.output_dir
    paths = {name: os.path.join(out_dir, f"{name}.fits")
             for name in ("source", "target", "aligned")}
    _check_output_dir(out_dir)
    # The demo's own earlier outputs are replaced (the README's command runs again); any
    # other file under those names is kept unless --overwrite.
    replace = {}
    for name, path in paths.items():
        replace[name] = args.overwrite
        if not replace[name] and os.path.isfile(path):
            try:  # a FITS file an earlier demo wrote (its header says so)
                replace[name] = fits.getval(path, _DEMO_KEY, ext=0) is True
            except (OSError, KeyError, IndexError, ValueError):
                pass
    for name, path in paths.items():
        _check_writable(path, replace[name])

    pair = simulate_pair(seed=args.seed, **DEMO_PAIR)
    meta = {_DEMO_KEY: (True, "written by astroalign-nd demo")}
    source = CCDData(pair.source, unit=u.adu, meta=dict(meta))
    target = CCDData(pair.target, unit=u.adu, meta=dict(meta))
    write_ccddata(source, paths["source"], overwrite=replace["source"])
    write_ccddata(target, paths["target"], overwrite=replace["target"])

    aligned = astroalign_nd.register(source, target)  # the source's header: AADEMO too
    write_ccddata(aligned, paths["aligned"], overwrite=replace["aligned"])

    # The registered frame records how it was made: rebuild the transform.
    recovered = astroalign_nd.transform_from_header(aligned.meta)
    # The largest distance (px) between the two transforms at the frame's corners.
    ny, nx = source.shape
    x = np.array([0.0, nx - 1.0, 0.0, nx - 1.0])
    y = np.array([0.0, 0.0, ny - 1.0, ny - 1.0])
    (xr, yr), (xt, yt) = recovered(x, y), pair.transform(x, y)
    error = float(np.max(np.hypot(np.asarray(xr) - xt, np.asarray(yr) - yt)))

    print(f"true transform:      {_describe(pair.transform)}")
    print(f"recovered transform: {_describe(recovered)}")
    print(f"max position error over the {source.shape[1]}x{source.shape[0]} frame: "
          f"{error:.4f} px")
    if not error < 1.0:
        print("WARNING: the recovered transform is more than 1 px off the truth somewhere "
              "in the frame.")
    print(f"wrote {paths['source']}")
    print(f"wrote {paths['target']}")
    print(f"wrote {paths['aligned']}")
    return 0
