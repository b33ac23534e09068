# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The declared minimum versions, as a pip constraints file, and a check that they are installed.

``python .ci/oldest_deps.py FILE`` writes ``name==floor`` for every runtime dependency in
pyproject.toml (``[project] dependencies`` and the runtime extras below); ``python
.ci/oldest_deps.py --check`` exits 1 unless the installed versions are those floors.  Test
tools are not constrained: they stay at their current versions.  A runtime dependency
without a ``>=`` floor is an error, so none can be left unpinned by accident.
"""

import re
import sys
import tomllib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

_REQ = re.compile(r"^\s*([A-Za-z0-9_.-]+)\s*(\[[^\]]*\])?\s*(.*)$")


def floors(pyproject=Path(__file__).resolve().parent.parent / "pyproject.toml"):
    """``{distribution name: floor}`` of every runtime dependency."""
    project = tomllib.loads(Path(pyproject).read_text(encoding="utf-8"))["project"]
    reqs = list(project["dependencies"])
    # The runtime extras are the ones the "all" extra names: astroalign_nd[exact,dask,...].
    runtime = re.search(r"\[(.*)\]", project["optional-dependencies"]["all"][0]).group(1)
    for extra in runtime.split(","):
        reqs += project["optional-dependencies"][extra]
    out = {}
    for req in reqs:
        name, _extras, spec = _REQ.match(req).groups()
        if name.lower().replace("_", "-") == "astroalign-nd":
            continue
        floor = [s.strip()[2:].strip() for s in spec.split(",") if s.strip().startswith(">=")]
        if not floor:
            raise SystemExit(f"{req!r} in pyproject.toml has no '>=' floor")
        out[name] = floor[0]
    return out


def _same(installed, floor):
    # "2024.1" is "2024.1.0"; compare the release numbers padded with zeros
    a = [int(p) for p in re.findall(r"\d+", installed.split("+")[0])]
    b = [int(p) for p in re.findall(r"\d+", floor)]
    n = max(len(a), len(b))
    return a + [0] * (n - len(a)) == b + [0] * (n - len(b))


def main(argv):
    if argv[1:] == ["--check"]:
        bad = 0
        for name, floor in floors().items():
            try:
                got = version(name)
            except PackageNotFoundError:
                got = "not installed"
            ok = got != "not installed" and _same(got, floor)
            bad += not ok
            print(f"{name:14s} declared >={floor:10s} installed {got}{'' if ok else '  <-- !'}")
        return 1 if bad else 0
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    Path(argv[1]).write_text("".join(f"{n}=={v}\n" for n, v in floors().items()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
