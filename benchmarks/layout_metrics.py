"""
The wiring of the package, counted from its source (no import of it).

Prints, for the non-test code under ``astroalign_nd/``:

* internal imports (of the package's own modules) placed inside functions,
  against all internal imports; imports of the heavy optional dependencies
  (matplotlib, dask, reproject, distributed) are listed apart;
* private names (``_x``) imported from another subpackage (a top-level
  module such as ``registration`` counts as its own subpackage);
* import cycles between modules, counting imports inside functions too;
* functions longer than ``--max-lines`` code lines (docstrings, comments and
  blank lines not counted);
* private module-level functions (``def _x``) per 1,000 code lines (the
  development guide's limit: 30);
* modules whose only statements are imports (and ``__all__``): re-exports
  (package ``__init__`` files, which declare a package's names, apart).

Usage::

    python benchmarks/layout_metrics.py [--root astroalign_nd] [--max-lines 60]
"""

import argparse
import ast
import pathlib
import sys

OPTIONAL = ("matplotlib", "dask", "distributed", "reproject")


def _module_name(path, root):
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _resolve(module, is_package, level, name):
    base = module.split(".") if is_package else module.split(".")[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def _subpackage(module, modules):
    """The subpackage a module belongs to ("" for the package's own top-level modules)."""
    parts = module.split(".")
    if len(parts) > 2 or (len(parts) == 2 and any(m.startswith(module + ".") for m in modules)):
        return parts[1]
    return ""


def _code_lines(node, source_lines):
    doc = set()
    body = getattr(node, "body", [])
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        doc = set(range(body[0].lineno, body[0].end_lineno + 1))
    count = 0
    for ln in range(node.lineno, node.end_lineno + 1):
        text = source_lines[ln - 1].strip()
        if text and not text.startswith("#") and ln not in doc:
            count += 1
    return count


def _docstring_lines(tree):
    """The line numbers of the module's, classes' and functions' docstrings."""
    out = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant) \
                and isinstance(body[0].value.value, str):
            out.update(range(body[0].lineno, body[0].end_lineno + 1))
    return out


def _is_all_or_doc(node):
    if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
        return True
    return isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == [
        "__all__"]


def _functions(tree):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


def analyse(root, max_lines):
    root = pathlib.Path(root).resolve()
    modules = {}
    for path in sorted(root.rglob("*.py")):
        if path.name == "_version.py":
            continue
        modules[_module_name(path, root)] = path
    names = set(modules)
    edges = {m: set() for m in modules}
    internal = inner = 0
    statements = inner_statements = 0
    optional_inner = []
    inner_outside_cli = []
    private = []
    long_functions = []
    code_lines = private_functions = 0
    reexports = []
    for mod, path in modules.items():
        text = path.read_text()
        tree = ast.parse(text)
        lines = text.split("\n")
        docs = _docstring_lines(tree)
        code_lines += sum(1 for ln, line in enumerate(lines, 1) if ln not in docs
                          and line.strip() and not line.strip().startswith("#"))
        if all(isinstance(n, (ast.Import, ast.ImportFrom)) or _is_all_or_doc(n)
               for n in tree.body):
            reexports.append(mod + (" (package)" if path.name == "__init__.py" else ""))
        private_functions += sum(1 for f in tree.body if isinstance(f, (
            ast.FunctionDef, ast.AsyncFunctionDef)) and f.name.startswith("_")
            and not f.name.startswith("__"))
        is_pkg = path.name == "__init__.py"
        func_ranges = [(f.lineno, f.end_lineno) for f in _functions(tree)]
        for f in _functions(tree):
            n = _code_lines(f, lines)
            if n > max_lines:
                long_functions.append((n, f"{mod}.{f.name}"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [(a.name, None) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = _resolve(mod, is_pkg, node.level, node.module)
                else:
                    base = node.module or ""
                targets = [(base, a.name) for a in node.names]
            else:
                continue
            in_function = any(a <= node.lineno <= b for a, b in func_ranges)
            if any(b.split(".")[0] == root.name for b, _ in targets):
                statements += 1
                inner_statements += in_function
                # The exemption: the CLI's lazy imports keep --help fast.
                if in_function and _subpackage(mod, names) != "cli":
                    inner_outside_cli.append(f"{mod}:{node.lineno}")
            for base, name in targets:
                top = base.split(".")[0]
                if top in OPTIONAL:
                    if in_function:
                        optional_inner.append(f"{mod}: {base}")
                    continue
                if top != root.name:
                    continue
                target = f"{base}.{name}" if name and f"{base}.{name}" in names else base
                if target not in names:
                    target = base
                if target == mod or target not in names:
                    continue
                internal += 1
                inner += in_function
                edges[mod].add(target)
                crosses = _subpackage(target, names) != _subpackage(mod, names)
                if name and name.startswith("_") and not name.startswith("__") and crosses:
                    private.append(f"{mod} <- {target}.{name}")
    cycles = _cycles(edges)
    return dict(modules=len(modules), internal=internal, inner=inner, statements=statements,
                inner_statements=inner_statements, inner_outside_cli=inner_outside_cli,
                optional_inner=optional_inner, private=private, cycles=cycles,
                code_lines=code_lines, private_functions=private_functions,
                reexports=reexports,
                long_functions=sorted(long_functions, reverse=True))


def _cycles(edges):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in edges:
        if v not in index:
            visit(v)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", default=str(pathlib.Path(__file__).parent.parent / "astroalign_nd"))
    ap.add_argument("--max-lines", type=int, default=60)
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    r = analyse(args.root, args.max_lines)
    share = r["inner"] / max(r["internal"], 1)
    print(f"{r['modules']} modules; internal imports inside functions: {r['inner']} of "
          f"{r['internal']} imported names ({share:.0%}), {r['inner_statements']} of "
          f"{r['statements']} import statements "
          f"({r['inner_statements'] / max(r['statements'], 1):.1%}); lazy optional "
          f"dependencies: {len(r['optional_inner'])}")
    outside = r["inner_outside_cli"]
    print(f"    of them outside cli/ (whose lazy imports keep --help fast): "
          f"{len(outside)} ({len(outside) / max(r['statements'], 1):.1%})"
          + ("" if not args.verbose else " " + ", ".join(outside)))
    print(f"private names imported across subpackages: {len(r['private'])}")
    if args.verbose:
        for p in r["private"]:
            print("   ", p)
    print(f"import cycles: {len(r['cycles'])}")
    for c in r["cycles"]:
        print("   ", " <-> ".join(c))
    print(f"private module-level functions: {r['private_functions']} in {r['code_lines']} code "
          f"lines ({1000 * r['private_functions'] / max(r['code_lines'], 1):.1f} per 1,000)")
    modules_only = [m for m in r["reexports"] if not m.endswith("(package)")]
    print(f"modules that only re-export: {len(modules_only)}; package __init__ files that "
          f"only import their names: {len(r['reexports']) - len(modules_only)}")
    if args.verbose:
        for m in r["reexports"]:
            print("   ", m)
    print(f"functions over {args.max_lines} code lines: {len(r['long_functions'])}")
    for n, f in r["long_functions"]:
        print(f"    {n:4d} {f}")


if __name__ == "__main__":
    main()
