"""``python/ferroslam/_core.pyi`` describes the native module exactly (names both ways).

The name checks parse the stub with ``ast``; the full signature check runs mypy's stubtest
when mypy happens to be installed (it is not a dependency).
"""

from __future__ import annotations

import ast
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

core = pytest.importorskip("ferroslam._core")

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "ferroslam"
STUB = PACKAGE / "_core.pyi"


def _public(name: str) -> bool:
    return not name.startswith("_")


def _stub_tree() -> ast.Module:
    return ast.parse(STUB.read_text(encoding="utf-8"), filename=str(STUB))


def _defined(body: list[ast.stmt]) -> set[str]:
    """Names a stub body defines (classes, functions, annotated or plain assignments)."""
    names: set[str] = set()
    for node in body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return names


def _stub_all(tree: ast.Module) -> list[str]:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
        ):
            return list(ast.literal_eval(node.value))
    raise AssertionError("the stub has no __all__")


def test_stub_and_marker_exist():
    assert STUB.is_file()
    assert (PACKAGE / "py.typed").is_file()


def test_module_names_match_both_ways():
    tree = _stub_tree()
    runtime = {n for n in dir(core) if _public(n)} | {"__version__"}
    stub = {n for n in _defined(tree.body) if _public(n)} | ({"__version__"} & _defined(tree.body))
    assert runtime - stub == set(), "in ferroslam._core but missing from the stub"
    assert stub - runtime == set(), "in the stub but not in ferroslam._core"
    assert sorted(_stub_all(tree)) == sorted(core.__all__)


def test_class_members_match_both_ways():
    classes = {n.name: n for n in _stub_tree().body if isinstance(n, ast.ClassDef)}
    for name, node in classes.items():
        if not _public(name):
            continue  # stub-only typing helpers such as _SlamOptions
        runtime_cls = getattr(core, name)
        # members the class itself defines (inherited object/Exception members excluded)
        runtime = {m for m in vars(runtime_cls) if _public(m)}
        stub = {m for m in _defined(node.body) if _public(m)}
        assert runtime == stub, f"{name}: runtime {sorted(runtime)} vs stub {sorted(stub)}"


def test_stub_is_final_where_the_runtime_class_cannot_be_subclassed():
    classes = {n.name: n for n in _stub_tree().body if isinstance(n, ast.ClassDef)}
    for name in ("SlamSystem", "TrackResult"):
        decorators = {d.id for d in classes[name].decorator_list if isinstance(d, ast.Name)}
        assert "final" in decorators
        with pytest.raises(TypeError):
            type("Sub", (getattr(core, name),), {})
    assert issubclass(core.SlamError, RuntimeError)


def test_system_options_in_stub_match_the_binding():
    """The ``_SlamOptions`` keys are exactly the names the binding accepts."""
    options = next(n for n in _stub_tree().body
                   if isinstance(n, ast.ClassDef) and n.name == "_SlamOptions")
    stub = sorted(_defined(options.body))
    with pytest.raises(ValueError, match="unknown option") as err:
        core.SlamSystem(500.0, 500.0, 320.0, 240.0, [], 640, 480, not_an_option=1)
    known = str(err.value).split("known: ", 1)[1]
    assert stub == sorted(k.strip() for k in known.split(","))


@pytest.mark.skipif(importlib.util.find_spec("mypy") is None, reason="mypy is not installed")
def test_stubtest():
    env = dict(os.environ, MYPYPATH=str(PACKAGE.parent))
    proc = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "ferroslam._core"],
        capture_output=True, text=True, env=env, timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
