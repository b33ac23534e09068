"""
Which frames, and how much: ``frame_quality``, ``stack(weights='auto',
select='auto')`` and ``normalize='stars'`` on a simulated night, against
equal weights, the ideal weights of the truth, and Siril 1.0.6; and the
same measures on real frames.

* A simulated night (``simulate_night``: 24 frames of 384x384, seeing
  2-8 px FWHM log-uniform with a 2.5 px reference, 3 frames at 40%
  transparency, 2 trailed to elongation 3, 1 satellite trail, 60 faint
  stars of 300 counts on a grid).  Stacks: equal weights (every frame),
  the ideal weights ``T**2 / (sigma**2 * A)`` from the true seeing,
  elongation, transparency and sky noise (every frame), ``weights='auto'``
  with ``select='auto'`` (and ``normalize='stars'``), and Siril's best
  filtered and weighted stack (``siril-cli``: ``register``, then ``stack
  rej 3 3 -norm=addscale`` with ``-filter-fwhm`` at 60/80/100% and
  ``-filter-round``, ``-weighted``; the best faint-star S/N is reported).
  Each stack's faint-star S/N: the mean flux of the faint stars in
  apertures of radius 0.7 x its FWHM over the scatter of the same
  apertures on blank sky (so the noise the interpolation correlates
  counts); its FWHM: the median of its bright stars' (adaptive moments).
* ``frame_quality``'s transparency against the known scaling (the frames
  not trailed), and the frames left out with their reasons.
* Equal-quality simulated frames (``simulate_sequence``, sub-pixel shifts,
  no uncertainty) and the five HAT-P-32 frames: the unresampled
  reference's weight against the others', and the stack's median
  uncertainty on the sky against the scatter measured on it (the median
  over 50x50 boxes of the sigma-clipped standard deviation).
* The Seestar subs of ``../shared/data/seestar_raw`` (raw Bayer frames)
  measured.

Usage::

    python benchmarks/bench_frame_quality.py
"""

import glob
import math
import os
import shutil
import subprocess
import tempfile
import warnings

import numpy as np

warnings.filterwarnings("ignore")

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data")
HATP = os.path.join(DATA, "real", "pairs", "exotic_hatp32_microobservatory")
SEESTAR = os.path.join(DATA, "seestar_raw")
FWHM_TO_SIGMA = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))


def faint_snr(image, night, rng_seed=0):
    """Mean faint-star aperture flux over the blank-aperture scatter, and the stack's FWHM."""
    from photutils.aperture import CircularAperture, aperture_photometry

    from astroalign_nd import find_sources
    from astroalign_nd.stacking.quality import _sky_map, star_shapes

    data = np.asarray(image, dtype=np.float64)
    ok = np.isfinite(data)
    data = np.where(ok, data, np.nanmedian(data))
    stars = find_sources(data, n_sources=60)
    fw, _ = star_shapes(data, np.asarray(stars["x"]), np.asarray(stars["y"]),
                        fwhm_guess=float(stars.meta["fwhm"]))
    fwhm = float(np.nanmedian(fw))
    sub = data - _sky_map(data, 64)
    r = 0.7 * fwhm
    fx, fy = night.meta["faint_x"], night.meta["faint_y"]
    flux = aperture_photometry(sub, CircularAperture(np.column_stack([fx, fy]), r=r))
    # Blank apertures: random positions far from every star and the edges.
    rng = np.random.default_rng(rng_seed)
    ny, nx = data.shape
    cand = rng.uniform(20, [nx - 20, ny - 20], (4000, 2))
    allx = np.concatenate([np.asarray(stars["x"]), fx, night.meta["star_x"]])
    ally = np.concatenate([np.asarray(stars["y"]), fy, night.meta["star_y"]])
    d = np.hypot(cand[:, :1] - allx[None], cand[:, 1:] - ally[None]).min(axis=1)
    blank = cand[d > 4 * fwhm + 6][:600]
    sky = aperture_photometry(sub, CircularAperture(blank, r=r))["aperture_sum"]
    from astropy.stats import sigma_clipped_stats

    _, _, noise = sigma_clipped_stats(np.asarray(sky, float), sigma=4)
    return float(np.mean(flux["aperture_sum"]) / noise), fwhm, len(blank)


def ideal_weights(night):
    m = night.meta
    sig = m["fwhm"] * FWHM_TO_SIGMA
    area = 4 * np.pi * sig ** 2 * m["elongation"]
    return m["transparency"] ** 2 / (m["sky_noise"] ** 2 * area)


def siril_stacks(frames, folder):
    """Siril 1.0.6's stacks of ``frames``: {label: data} (empty without siril-cli)."""
    from astropy.io import fits

    exe = shutil.which("siril-cli")
    if exe is None:
        return {}
    os.makedirs(folder, exist_ok=True)
    for k, f in enumerate(frames):
        fits.writeto(os.path.join(folder, f"raw_{k + 1:05d}.fit"),
                     np.asarray(f.data, np.float32), overwrite=True)
    variants = {"rej 3 3, addscale (all)": "",
                "-weighted": " -weighted",
                "-filter-fwhm=80%": " -filter-fwhm=80%",
                "-filter-fwhm=80% -filter-round=80% -weighted":
                    " -filter-fwhm=80% -filter-round=80% -weighted",
                "-filter-fwhm=60% -filter-round=80% -weighted":
                    " -filter-fwhm=60% -filter-round=80% -weighted"}
    scripts = [["link night -out=.", "register night"]]
    # One script per stack: an option this version does not know fails alone.
    scripts += [[f"stack r_night rej 3 3 -norm=addscale{opts} -out=out{k}"]
                for k, opts in enumerate(variants.values())]
    logs = []
    for k, lines in enumerate(scripts):
        path = os.path.join(folder, f"run{k}.ssf")
        with open(path, "w") as fh:
            fh.write("\n".join(["requires 1.0.0", "setext fit"] + lines) + "\n")
        proc = subprocess.run([exe, "-d", folder, "-s", path], capture_output=True,
                              text=True, timeout=900)
        logs.append(proc.stdout[-1500:])
    out = {}
    for k, label in enumerate(variants):
        path = os.path.join(folder, f"out{k}.fit")
        if os.path.exists(path):
            out[label] = fits.getdata(path).astype(np.float64)
    for k, label in enumerate(variants, start=1):
        if label not in out:
            print(f"Siril: '{label}' failed:", logs[k][-400:].replace("\n", " | "))
    return out


def night_part(tmp):
    from astroalign_nd import frame_quality, stack
    from astroalign_nd.simulate import simulate_night

    night = simulate_night((384, 384), n_frames=24, n_faint=60, n_stars=200, seed=38)
    m = night.meta
    print("== simulated night: 24 frames, 384x384 ==")
    table = frame_quality(night.frames, select="auto")
    table["true_fwhm"] = np.round(m["fwhm"], 2)
    table["true_T"] = m["transparency"]
    table["true_elong"] = m["elongation"]
    table["satellite"] = m["satellite"]
    cols = ["name", "fwhm", "true_fwhm", "elongation", "true_elong", "transparency", "true_T",
            "sky_noise", "star_ratio", "rms", "weight", "used", "satellite"]
    table[cols].pprint(max_lines=-1, max_width=-1)
    for row in table:
        if not row["used"]:
            print(f"  left out {row['name']}: {row['reason']}")
    good = ~m["trailed"]
    err = np.abs(np.asarray(table["transparency"]) / m["transparency"] - 1)[good]
    sharp = (m["fwhm"] < 5.0)[good]
    print(f"transparency vs truth (frames not trailed): median |error| "
          f"{100 * np.nanmedian(err):.1f}%, max {100 * np.nanmax(err):.1f}%; "
          f"seeing < 5 px: max {100 * np.nanmax(err[sharp]):.1f}%")
    left = ~np.asarray(table["used"])
    trailed_out = all("trailed" in table["reason"][i] for i in np.flatnonzero(m["trailed"]))
    good_frames = ~(m["trailed"] | m["cloudy"])
    print(f"trailed frames left out as 'trailed': {trailed_out}; good frames left out: "
          f"{int((left & good_frames).sum())}; cloudy frames left out: "
          f"{int((left & m['cloudy']).sum())}")

    rows = []
    runs = {"equal weights": dict(weights=None),
            "inverse variance (default)": dict(),
            "ideal weights (truth), normalize='stars'": dict(
                weights=ideal_weights(night), normalize="stars"),
            "weights='auto'": dict(weights="auto"),
            "weights='auto', select='auto'": dict(weights="auto", select="auto"),
            "weights='auto', normalize='stars'": dict(weights="auto", normalize="stars"),
            "equal weights, order='bicubic'": dict(weights=None, order="bicubic"),
            "weights='auto', select='auto', order='bicubic'": dict(
                weights="auto", select="auto", order="bicubic"),
            "equal weights, star_tolerance=0 (plain clip)": dict(
                weights=None, star_tolerance=0),
            "ideal weights, star_tolerance=0 (plain clip)": dict(
                weights=ideal_weights(night), normalize="stars", star_tolerance=0)}
    snr = {}
    for label, kw in runs.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ccd = stack(night.frames, **kw)
        s, fw, _ = faint_snr(ccd.data, night)
        snr[label] = (s, fw)
        rows.append((label, ccd.meta["NCOMBINE"], s, fw))
    for label, data in siril_stacks(night.frames, os.path.join(tmp, "siril")).items():
        s, fw, _ = faint_snr(data, night)
        rows.append(("Siril 1.0.6 " + label, -1, s, fw))
    eq = snr["equal weights"][0]
    ideal = snr["ideal weights (truth), normalize='stars'"][0]
    print(f"\n{'stack':52s} {'frames':>6s} {'faint S/N':>9s} {'/equal':>7s} {'/ideal':>7s} "
          f"{'FWHM':>5s}")
    for label, n, s, fw in rows:
        print(f"{label:52s} {n if n >= 0 else '?':>6} {s:9.2f} {s / eq:7.3f} {s / ideal:7.3f} "
              f"{fw:5.2f}")
    return table


def sky_scatter(ccd):
    """The median over 50x50 boxes of the sigma-clipped std, and the median uncertainty."""
    from astropy.stats import sigma_clipped_stats

    d = np.asarray(ccd.data, float)
    ok = ~np.asarray(ccd.mask) & np.isfinite(d)
    stds = []
    for y0 in range(0, d.shape[0] - 49, 50):
        for x0 in range(0, d.shape[1] - 49, 50):
            sl = np.s_[y0:y0 + 50, x0:x0 + 50]
            if ok[sl].all():
                stds.append(sigma_clipped_stats(d[sl], sigma=3, maxiters=10)[2])
    # The same at the scale of an aperture: the scatter of 5x5 block means times 5
    # (the per-pixel noise an aperture sum sees; the interpolation's correlation
    # lowers the per-pixel scatter, not this).
    blocks = []
    for y0 in range(0, d.shape[0] - 49, 50):
        for x0 in range(0, d.shape[1] - 49, 50):
            sl = np.s_[y0:y0 + 50, x0:x0 + 50]
            if ok[sl].all():
                b = d[sl].reshape(10, 5, 10, 5).mean(axis=(1, 3))
                blocks.append(5 * sigma_clipped_stats(b, sigma=3, maxiters=10)[2])
    u = np.asarray(ccd.uncertainty.array, float)
    _, med, std = sigma_clipped_stats(d[ok], sigma=3, maxiters=10)
    sky = ok & (np.abs(d - med) < 2 * std)
    return float(np.median(stds)), float(np.median(blocks)), float(np.median(u[sky]))


def noise_part(label, frames):
    from astroalign_nd import stack

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ccd = stack(frames)
    h = ccd.meta
    n = h["NCOMBINE"]
    w = [h[f"AAWGT{k:03d}"] for k in range(1, n + 1)]
    nrej = [h[f"AANRJ{k:03d}"] for k in range(1, n + 1)]
    noise = [h.get(f"AANOI{k:03d}") for k in range(1, n + 1)]
    scatter, block, unc = sky_scatter(ccd)
    others = np.median(w[1:])
    print(f"{label}: weights {np.round(w, 3).tolist()} (reference / median of the others "
          f"{w[0] / others:.3f}); sky noise as taken {noise}; rejected pixels {nrej}; "
          f"stack median uncertainty {unc:.3f} vs measured scatter {scatter:.3f} "
          f"(ratio {unc / scatter:.3f}); vs 5x5-block scatter x 5 {block:.3f} "
          f"(ratio {unc / block:.3f})")


def real_part():
    from astroalign_nd import frame_quality
    from astroalign_nd.simulate import simulate_sequence

    seq = simulate_sequence((256, 256), n_frames=5, n_stars=150, integer_shifts=False,
                            uncertainty=False, seed=7)
    print("\n== noise where it belongs ==")
    noise_part("simulated, equal quality (5 frames, sub-pixel shifts)", seq.frames)
    hat = sorted(glob.glob(os.path.join(HATP, "*.FITS")))
    if hat:
        noise_part("HAT-P-32 (5 frames)", hat)
        print("\n== HAT-P-32: frame_quality ==")
        t = frame_quality(hat, select="auto")
        t["name"] = [os.path.basename(n) for n in t["name"]]
        t.pprint(max_lines=-1, max_width=-1)
    sub = sorted(glob.glob(os.path.join(SEESTAR, "*.fit*")))
    if sub:
        print("\n== Seestar subs (raw Bayer): frame_quality ==")
        t = frame_quality(sub, select="auto")
        t["name"] = [os.path.basename(n)[-22:] for n in t["name"]]
        t.pprint(max_lines=-1, max_width=-1)


def main():
    with tempfile.TemporaryDirectory() as tmp:
        night_part(tmp)
    real_part()


if __name__ == "__main__":
    main()
