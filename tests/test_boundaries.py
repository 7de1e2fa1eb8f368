"""Imports point one way: hil -> firmware_py, plant_sim; never back, never across."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imported_top_levels(package: str) -> set[tuple[str, str]]:
    found = set()
    for path in (ROOT / package).rglob("*.py"):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                found |= {(str(path.relative_to(ROOT)), a.name.split(".")[0]) for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add((str(path.relative_to(ROOT)), node.module.split(".")[0]))
    return found


@pytest.mark.parametrize("package, forbidden", [
    ("firmware_py", {"hil", "plant_sim", "can", "cantools", "serial", "socket", "time"}),
    ("plant_sim", {"hil", "firmware_py", "can", "cantools", "serial", "socket", "time"}),
])
def test_pure_packages_import_neither_hil_nor_each_other_nor_io(package, forbidden):
    bad = sorted((f, m) for f, m in imported_top_levels(package) if m in forbidden)
    assert not bad, f"{package} imports {bad}"
    assert (ROOT / package / "__init__.py").exists()
