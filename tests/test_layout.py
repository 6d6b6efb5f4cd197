"""The code's layout rules, checked on the source: no two files import each other (Python
imports, Rust ``crate::`` and ``super::`` paths between the files of a crate), no Rust source
file over 900 lines."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_RUST_LINES = 900


def _mutual(edges: dict[str, set[str]]) -> list[tuple[str, str]]:
    return sorted((a, b) for a in edges for b in edges[a] if a < b and a in edges.get(b, ()))


def _python_imports() -> dict[str, set[str]]:
    package = ROOT / "python" / "ferroslam"
    modules = {}
    for f in package.rglob("*.py"):
        name = ".".join(f.relative_to(package.parent).with_suffix("").parts)
        modules[name.removesuffix(".__init__")] = f
    edges: dict[str, set[str]] = {m: set() for m in modules}
    for name, f in modules.items():
        here = name if f.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = here.split(".")[: len(here.split(".")) - node.level + 1] if node.level \
                    else []
                target = ".".join(base + ([node.module] if node.module else []))
                targets = [target] + [f"{target}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            edges[name].update(t for t in targets if t in modules and t != name)
    return edges


def _rust_module(src: Path, f: Path) -> tuple[str, ...]:
    parts = f.relative_to(src).with_suffix("").parts
    if parts[-1] in ("mod", "lib"):
        parts = parts[:-1]
    return parts


def _rust_imports(src: Path) -> dict[str, set[str]]:
    files = {_rust_module(src, f): f for f in src.rglob("*.rs")}
    edges: dict[str, set[str]] = {}
    for module, f in files.items():
        # code only: not the unit tests at the end, not comments (doc links are no imports)
        text = re.sub(r"#\[cfg\(test\)\]\s*mod tests \{.*", "", f.read_text(encoding="utf-8"),
                      flags=re.S)
        text = re.sub(r"//.*", "", text)
        targets = set()
        for path in re.findall(r"\b((?:crate|super)(?:::\w+)+)", text):
            head, *rest = path.split("::")
            parent = module if f.stem in ("mod", "lib") else module[:-1]
            base = () if head == "crate" else parent[:-1]
            segments = (*base, *rest)
            # the longest prefix that is a file of this crate
            for n in range(len(segments), 0, -1):
                if segments[:n] in files and segments[:n] != module:
                    targets.add("::".join(segments[:n]))
                    break
        edges["::".join(module)] = targets
    return edges


def test_no_two_python_modules_import_each_other():
    assert _mutual(_python_imports()) == []


def test_no_two_rust_files_import_each_other():
    cycles = {}
    for src in sorted(ROOT.glob("crates/*/src")):
        pairs = _mutual(_rust_imports(src))
        if pairs:
            cycles[src.parent.name] = pairs
    assert cycles == {}


def test_no_rust_source_file_over_900_lines():
    long = {str(f.relative_to(ROOT)): n for f in ROOT.glob("crates/*/src/**/*.rs")
            if (n := len(f.read_text(encoding="utf-8").splitlines())) > MAX_RUST_LINES}
    assert long == {}
