"""The import rules of the layers, read from the source (ast): what each product module
imports at module level, and that the module-level import graph has no cycle.

Layers (README "Architecture"): ``core`` (types, geometry, errors) imports nothing above
it; ``io``, ``frontend`` and ``backend`` import ``core`` and themselves only -- never each
other (the front-end reads no file), never the pipeline/CLI package; the pipeline and CLI
(``planar_vo`` outside ``sim``/``bench``) import no workshop module at module level (the
``synth``, ``demo`` and ``bench`` commands load it when run), and nothing in the product
imports open3d, the workshop's extra.
"""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: import name -> folder, as setup.py installs them
ROOTS = {"planar_vo": "planar_vo", "planar_vo.core": "core", "planar_vo.frontend": "frontend",
         "planar_vo.backend": "backend", "planar_vo.io": "io", "planar_vo.data": "data"}
WORKSHOP = ("planar_vo.sim", "planar_vo.bench")
ALLOWED = {  # layer -> the planar_vo packages its modules may import at module level
    "planar_vo.core": ("planar_vo.core",),
    "planar_vo.io": ("planar_vo.core", "planar_vo.io"),
    "planar_vo.frontend": ("planar_vo.core", "planar_vo.frontend"),
    "planar_vo.backend": ("planar_vo.core", "planar_vo.backend"),
}


def _modules() -> dict[str, Path]:
    out = {}
    for name, folder in ROOTS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT / folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            mod = ".".join([name, *parts])
            if mod.split(".")[:2] == ["planar_vo", "data"] and name == "planar_vo":
                continue
            out[mod] = path
    return out


MODULES = _modules()


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or \
        (isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def module_level_imports(path: Path, module: str) -> set[str]:
    """Absolute names imported when the module is imported (not inside functions or classes,
    not under ``if TYPE_CHECKING``)."""
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()

    def visit(body):
        for node in body:
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
                for a in node.names:  # "from pkg import mod" imports pkg.mod when it is a module
                    found.add(f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base)
            elif isinstance(node, ast.If) and not _is_type_checking(node):
                visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)
                for h in node.handlers:
                    visit(h.body)
                visit(node.orelse)
                visit(node.finalbody)

    visit(tree.body)
    return found


IMPORTS = {m: module_level_imports(p, m) for m, p in MODULES.items()}


def _layer(module: str) -> str:
    return ".".join(module.split(".")[:2]) if module != "planar_vo" else module


def _within(name: str, packages) -> bool:
    return any(name == p or name.startswith(p + ".") for p in packages)


def _product(module: str) -> bool:
    return not _within(module, WORKSHOP)


def test_modules_found():
    assert {"planar_vo.core.types", "planar_vo.io.log", "planar_vo.frontend.odometry",
            "planar_vo.backend.graph", "planar_vo.pipeline", "planar_vo.sim.synth"} <= set(MODULES)


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _layer(m) in ALLOWED))
def test_layer_imports_only_below(module):
    allowed = ALLOWED[_layer(module)]
    bad = sorted(n for n in IMPORTS[module] if _within(n, ("planar_vo",)) and not _within(n, allowed))
    assert not bad, f"{module} imports {bad}; a {_layer(module)} module may import only {allowed}"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _product(m)))
def test_product_imports_no_workshop(module):
    bad = sorted(n for n in IMPORTS[module] if _within(n, WORKSHOP) or _within(n, ("open3d",)))
    assert not bad, f"{module} imports {bad} at module level (workshop: load it where it is used)"


def test_top_package_is_light():
    """Importing any layer imports ``planar_vo/__init__.py`` first: it must import nothing."""
    assert not IMPORTS["planar_vo"], IMPORTS["planar_vo"]


def test_no_module_level_import_cycle():
    # Explicit imports only: a package's __init__ importing its own modules is no cycle
    # (the package is in sys.modules while they load), a module importing a name of a package
    # whose __init__ imports that module back is.
    graph = {m: {n for n in IMPORTS[m] if n in MODULES and n != m} for m in MODULES}
    state, stack = {}, []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == "open":
                cycle = stack[stack.index(n):] + [n]
                pytest.fail("module-level import cycle: " + " -> ".join(cycle))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = "done"

    for m in sorted(MODULES):
        if m not in state:
            visit(m)


def test_layers_do_not_import_planar_vo_inside_functions():
    """io, frontend, backend and core import what they use at the top of the module."""
    offenders = []
    for m, path in MODULES.items():
        if _layer(m) not in ALLOWED:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for inner in ast.walk(node):
                    if isinstance(inner, ast.ImportFrom) and (inner.module or "").startswith("planar_vo"):
                        offenders.append(f"{m}:{inner.lineno} {inner.module}")
    assert not offenders, offenders


def test_demo_without_the_sim_extra_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    """The demo renders its log with the simulator; without open3d it fails with one line
    naming the extra (and creates nothing)."""
    import sys

    from planar_vo.cli import main

    monkeypatch.setitem(sys.modules, "open3d", None)  # import open3d -> ImportError
    assert main(["demo", "--samples", str(tmp_path / "samples"), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'planar-vo[sim]'" in err[0]
    assert not (tmp_path / "samples").exists()
