# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Run astroalign's own test suite, straight from its sdist, against astroalign_nd.compat.

Usage::

    python tests/astroalign_suite/run_upstream.py [--sdist PATH] [pytest options]

Downloads ``astroalign==2.6.2``'s source distribution with pip (or uses
``--sdist``), takes ``tests/test_align.py`` out of it unchanged, makes
``import astroalign`` resolve to `astroalign_nd.compat` and runs the file
with pytest under its own defaults (not this project's configuration).  The
exit status is pytest's.  ``tox -e astroalign_suite`` runs this.
"""

import argparse
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

VERSION = "2.6.2"
MEMBER = f"astroalign-{VERSION}/tests/test_align.py"


def fetch_sdist(directory):
    """Download the sdist into ``directory``; return its path."""
    subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary",
                    ":all:", f"astroalign=={VERSION}", "-d", str(directory)], check=True)
    found = sorted(Path(directory).glob(f"astroalign-{VERSION}.tar.gz"))
    if not found:
        raise SystemExit(f"pip did not leave astroalign-{VERSION}.tar.gz in {directory}")
    return found[0]


def extract_suite(sdist, directory):
    """Write the sdist's tests/test_align.py into ``directory``; return its path."""
    with tarfile.open(sdist) as tar:
        try:
            data = tar.extractfile(MEMBER).read()
        except KeyError:
            raise SystemExit(f"{sdist} has no {MEMBER}") from None
    path = Path(directory) / "test_align.py"
    path.write_bytes(data)
    return path


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sdist", help="an already downloaded astroalign sdist (.tar.gz)")
    args, pytest_args = parser.parse_known_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        sdist = Path(args.sdist) if args.sdist else fetch_sdist(tmp)
        test_file = extract_suite(sdist, tmp)
        import pytest

        from astroalign_nd import compat

        sys.modules["astroalign"] = compat  # what `import astroalign as aa` gets
        print(f"astroalign {VERSION}'s tests/test_align.py against {compat.__file__}")
        return pytest.main([str(test_file), "-p", "no:cacheprovider", "--rootdir", tmp,
                            "-c", os.devnull, *pytest_args])


if __name__ == "__main__":
    sys.exit(main())
