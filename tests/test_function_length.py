"""No function longer than 60 lines in the product (core, io, frontend, backend, and the
pipeline/CLI package outside the workshop's sim/ and bench/): ast, ``end_lineno - lineno``."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("core", "io", "frontend", "backend", "planar_vo")
WORKSHOP = ("sim", "bench")
MAX_LINES = 60


def _product_files():
    for folder in PRODUCT:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if not set(path.relative_to(ROOT).parts[:-1]) & set(WORKSHOP):
                yield path


def test_the_walk_sees_the_product():
    names = {p.relative_to(ROOT).as_posix() for p in _product_files()}
    assert {"planar_vo/pipeline.py", "frontend/estimators.py", "backend/graph.py", "io/mcap_reader.py",
            "core/geometry.py"} <= names
    assert not any("/sim/" in n or "/bench/" in n for n in names)


def test_no_long_function():
    long = []
    for path in _product_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno
                if n > MAX_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert not long, "functions longer than 60 lines: " + "; ".join(long)
