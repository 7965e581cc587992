"""The package's architecture, checked in ``make test`` (and so in CI).

* The import-linter contracts in ``pyproject.toml`` (``[tool.importlinter]``, also run by
  ``make lint``): the layers of the pipeline, no import cycles, independent commands.
* Function-local ``poise`` imports: allowed only where they keep start-up light, said by a
  comment containing ``lazy`` on the import, or above it in the same block of imports. The
  modules that still have others are listed in :data:`ALLOWED` with their count; the count may
  only go down (shrink the list as the imports move to the top of their modules).
"""
from __future__ import annotations

import ast
import os
from pathlib import Path

import pytest

from support.paths import ROOT


PACKAGES = (ROOT / "src" / "poise", ROOT / "cli" / "poise_cli")

# module (path from the repository root) -> function-local poise imports without a `lazy` comment
ALLOWED = {
}


def _is_poise_import(node: ast.AST) -> bool:
    if isinstance(node, ast.Import):
        return any(a.name == "poise" or a.name.startswith("poise.") for a in node.names)
    if isinstance(node, ast.ImportFrom):
        mod = node.module or ""
        return node.level > 0 or mod == "poise" or mod.startswith("poise.")
    return False


def _commented_lazy(lines: list[str], node: ast.stmt) -> bool:
    """``lazy`` in a comment on the statement's lines, or on a comment line above it with only
    imports (and comments) in between."""
    if any("#" in ln and "lazy" in ln.split("#", 1)[1]
           for ln in lines[node.lineno - 1:node.end_lineno]):
        return True
    i = node.lineno - 2
    while i >= 0:
        s = lines[i].strip()
        if s.startswith("#"):
            if "lazy" in s:
                return True
        elif not s.startswith(("from ", "import ")) and not s.endswith(("\\", ",")) \
                and not s.startswith(")"):
            return False
        i -= 1
    return False


def local_imports(path: Path) -> tuple[int, int]:
    """(function-local poise imports without a lazy comment, with one)."""
    text = path.read_text()
    lines = text.splitlines()
    plain = lazy = 0

    def walk(node: ast.AST, in_function: bool) -> None:
        nonlocal plain, lazy
        for child in ast.iter_child_nodes(node):
            if in_function and _is_poise_import(child):
                if _commented_lazy(lines, child):
                    lazy += 1
                else:
                    plain += 1
            walk(child, in_function or isinstance(
                child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    walk(ast.parse(text), False)
    return plain, lazy


def test_function_local_poise_imports_only_where_they_keep_start_up_light():
    found = {}
    for pkg in PACKAGES:
        for path in sorted(pkg.rglob("*.py")):
            plain, _ = local_imports(path)
            if plain:
                found[path.relative_to(ROOT).as_posix()] = plain
    grown = {m: (n, ALLOWED.get(m, 0)) for m, n in found.items() if n > ALLOWED.get(m, 0)}
    assert not grown, ("function-local poise imports without a `# lazy: why` comment "
                       f"(module: (found, allowed)): {grown}; import at the top of the module")
    shrunk = {m: (found.get(m, 0), n) for m, n in ALLOWED.items() if found.get(m, 0) < n}
    assert not shrunk, f"fewer function-local imports than allowed, lower ALLOWED: {shrunk}"


def test_import_contracts_are_kept():
    """``lint-imports`` (the contracts of pyproject.toml) passes; CI installs the dev extra."""
    if os.environ.get("CI"):
        from importlinter.cli import lint_imports
    else:
        lint_imports = pytest.importorskip("importlinter.cli").lint_imports
    rc = lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True)
    assert rc == 0, "import contracts broken: run `make lint` (lint-imports) for the report"


#: every package of poise: no module imports a private name (``_name``) of another module
NO_PRIVATE_IMPORTS = tuple(sorted(p.name for p in PACKAGES[0].iterdir()
                                  if (p / "__init__.py").is_file()))


def _private_uses(path: Path) -> list[str]:
    """``from X import _name`` and ``module._name`` of another poise module in ``path``."""
    tree = ast.parse(path.read_text())
    modules, out = set(), []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith(
                "poise")):
            for a in node.names:
                if a.name.startswith("_") and not a.name.startswith("__"):
                    out.append(f"{path.name}:{node.lineno}: imports {a.name}")
                else:
                    modules.add(a.asname or a.name)
        elif isinstance(node, ast.Import):
            modules |= {a.asname or a.name.split(".")[0] for a in node.names
                        if a.name.startswith("poise")}
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and \
                node.value.id in modules and node.attr.startswith("_") and \
                not node.attr.startswith("__"):
            out.append(f"{path.name}:{node.lineno}: {node.value.id}.{node.attr}")
    return out


def test_no_private_names_across_modules():
    assert {"solvers", "results", "app"} <= set(NO_PRIVATE_IMPORTS)
    bad = [u for pkg in NO_PRIVATE_IMPORTS for p in sorted((PACKAGES[0] / pkg).rglob("*.py"))
           for u in _private_uses(p)]
    assert bad == []


def _path_literals(path: Path) -> list[str]:
    """String constants of ``path`` (docstrings aside; f-string pieces too) that name a results
    file path: ``group/name`` or ``group/`` (``frames/status``, ``f"steps/{k}"``)."""
    import re
    tree = ast.parse(path.read_text())
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and n.body and isinstance(n.body[0], ast.Expr)
            and isinstance(n.body[0].value, ast.Constant)}
    return [f"{path.name}:{n.lineno}: {n.value!r}" for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
            and re.match(r"[a-z][a-z0-9_]*/([a-z_]|$)", n.value)]


def test_only_the_results_layout_knows_file_paths():
    """The solvers hand on typed records; poise.results.layout maps them onto the file: no
    results path literal under src/poise/solvers (issue 24)."""
    bad = [u for p in sorted((PACKAGES[0] / "solvers").rglob("*.py")) for u in _path_literals(p)]
    assert bad == []
    assert _path_literals(PACKAGES[0] / "results" / "layout.py")      # the check sees them


def test_no_test_group_imports_another():
    """Test modules import shared helpers from ``tests/support`` only, never from another test
    module or group (tests/README.md)."""
    tests = ROOT / "tests"
    groups = {p.name for p in tests.iterdir() if p.is_dir() and p.name not in ("support", "data")}
    stems = {p.stem for p in tests.rglob("test_*.py")}
    bad = []
    for p in sorted(tests.rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            if isinstance(node, ast.ImportFrom) and node.level:
                names = ["." + (node.module or "")]
            for n in names:
                top = n.split(".")[0]
                if n.startswith(".") or top in groups or top in stems or top == "tests":
                    bad.append(f"{p.relative_to(tests)}:{node.lineno}: {n}")
    assert bad == []
