"""
``register`` time with a large ``meta`` (issue 25: 20,000 keys took 28 s).

Registers one simulated 256x256 pair with a CCDData source whose meta holds
0 or ``--keys`` entries (integers, strings, or an astropy Header), median of
``--repeats`` runs each, and prints the times and the output header's size.

Usage::

    python benchmarks/bench_header_meta.py [--keys 20000] [--repeats 3]
"""

import argparse
import statistics
import time

from astropy.io import fits
from astropy.nddata import CCDData

from astroalign_nd import register
from astroalign_nd.simulate import simulate_pair


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keys", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    pair = simulate_pair((256, 256), n_stars=150, rotation=20.0, seed=2)
    n = args.keys
    metas = {"no meta": {}, f"{n} int keys": {f"KEY{i:05d}": i for i in range(n)},
             f"{n} str keys": {f"KEY{i:05d}": f"value {i}" for i in range(n)},
             f"{n}-card Header": fits.Header([(f"KEY{i:05d}", i) for i in range(n)])}
    for name, meta in metas.items():
        times = []
        for _ in range(args.repeats):
            src = CCDData(pair.source, unit="adu", meta=meta)
            t0 = time.perf_counter()
            out = register(src, pair.target)
            times.append(time.perf_counter() - t0)
        print(f"{name:>20s}: {statistics.median(times):6.2f} s  ({len(out.meta)} cards)")


if __name__ == "__main__":
    main()
