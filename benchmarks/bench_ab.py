"""
A/B timing of ``register`` between this checkout and another copy of the
package, interleaved in one process (issue 10: "register time within 10%").

The other copy is imported under another name: copy its ``astroalign_nd``
folder (with its compiled extension) to ``DIR/astroalign_nd_old`` and pass
``--old DIR``.  Both run on the same simulated ndarray pairs, alternately,
and astroalign on the same pairs gives the usual ratio.

Usage::

    python benchmarks/bench_ab.py --old /tmp/oldpkg [--repeats 5]
"""

import argparse
import sys
import time
import warnings

import numpy as np

warnings.simplefilter("ignore")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--old", required=True, help="folder holding astroalign_nd_old/")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    sys.path.insert(0, args.old)
    import astroalign
    import astroalign_nd as new
    import astroalign_nd_old as old
    from astroalign_nd.simulate import simulate_pair

    print(f"{'size':>6s} {'stars':>6s} {'new s':>8s} {'old s':>8s} {'new/old':>8s} "
          f"{'aa s':>8s} {'new/aa':>7s} {'old/aa':>7s}")
    for size, n in ((1024, 1000), (4096, 3000)):
        pair = simulate_pair((size, size), n_stars=n, rotation=30.0, scale=1.02,
                             noise="gaussian", seed=1)
        src = np.asarray(pair.source, np.float32)
        dst = np.asarray(pair.target, np.float32)
        for mod in (new, old):  # warm-up
            mod.register(src, dst)
        times = {"new": [], "old": [], "aa": []}
        for _ in range(args.repeats):
            for key, fn in (("new", lambda: new.register(src, dst)),
                            ("old", lambda: old.register(src, dst)),
                            ("aa", lambda: astroalign.register(src, dst))):
                t0 = time.perf_counter()
                fn()
                times[key].append(time.perf_counter() - t0)
        m = {k: float(np.median(v)) for k, v in times.items()}
        print(f"{size:6d} {n:6d} {m['new']:8.3f} {m['old']:8.3f} {m['new'] / m['old']:8.2f} "
              f"{m['aa']:8.3f} {m['new'] / m['aa']:7.2f} {m['old'] / m['aa']:7.2f}", flush=True)


if __name__ == "__main__":
    main()
