"""The package layout's rule that import-linter cannot check: no module imports another's private names."""

import ast
from pathlib import Path

import acn

ROOT = Path(acn.__file__).parent


def _private_imports() -> list[str]:
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("acn")):
                found += [f"{path.relative_to(ROOT.parent)}: from {'.' * node.level}{node.module or ''} import {a.name}"
                          for a in node.names if a.name.startswith("_")]
    return found


def test_no_module_imports_another_modules_private_names():
    assert _private_imports() == []
