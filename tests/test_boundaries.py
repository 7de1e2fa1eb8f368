"""Imports point one way.

- firmware_py and plant_sim import neither hil nor each other, nor anything that does I/O.
- Inside hil, the wings form layers and every import points to the same layer or a lower one:

      cli, pytest plugin  →  studies  →  safety / report / campaign / typetest  →  runtime / devices / fmi
                          →  can / trace / scenario / links  →  errors, resources, progress, build

  The runtime runs a scenario and leaves its run folder; the report reads it (hil.report.run also holds the
  entry points that run and then report), and a lockstep run's caller hands the runtime its fault injector
  (hil.runtime.lockstep.FaultHook): no arrow from the runtime up to report or safety.

- No import circles between modules.
- railhil's own modules are imported at module level.  An import inside a function is kept only where a
  measured start-up cost needs it, and says so on the line above it (or above its group of imports):
  ``# lazy: <reason>, N ms ...`` -- e.g. the pytest plugin, which every pytest session loads.

Imports are read from the source (AST), at module level and inside functions alike, and a string
constant that names a hil module (`"hil.cli.run"` in a table that importlib loads) counts as an import
of it.  The one arrow that points up by design is the scenario's lookup of the study registry by name
(`ALLOWED_UPWARD`): the foundation knows the studies only through that registry.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: hil's layers, lowest first: a module belongs to the first prefix it starts with
LAYERS: list[tuple[str, ...]] = [
    ("hil.errors", "hil.resources", "hil.progress", "hil.build"),
    ("hil.can", "hil.trace", "hil.scenario", "hil.links"),
    ("hil.runtime", "hil.devices", "hil.fmi"),
    ("hil.safety", "hil.report", "hil.campaign", "hil.typetest"),
    ("hil.studies",),
    ("hil.cli", "hil.pytest_plugin", "hil.__main__", "hil"),
]
#: (importer, imported) arrows that point up by design, with the reason
ALLOWED_UPWARD = {
    ("hil.scenario.registry", "hil.studies"):
        "the foundation reads the study registry by name, the way python-can loads its interfaces",
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def all_modules(package: str) -> dict[str, Path]:
    return {module_name(p): p for p in sorted((ROOT / package).rglob("*.py"))}


def imports_of(path: Path, name: str, known: dict[str, Path]) -> set[str]:
    """The hil, firmware_py and plant_sim modules `path` imports (resolved to modules that exist)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()

    def add(target: str) -> None:
        while target and target not in known:          # `from hil.can import codec` -> hil.can.codec
            target = target.rpartition(".")[0]
        if target:
            found.add(target)

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:
                full = f"{module}.{alias.name}"
                add(full if full in known else module)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in known \
                and node.value.startswith("hil.") and not name.startswith(node.value + "."):
            add(node.value)                            # a module named in a table importlib loads (a
            #                                            module naming its own package is not one)
    found.discard(name)
    return found


def layer_of(module: str) -> int:
    for level, prefixes in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return level
    raise AssertionError(f"{module}: in no layer of tests/test_boundaries.py LAYERS; add its wing there")


def hil_graph() -> tuple[dict[str, Path], dict[str, set[str]]]:
    known = {**all_modules("hil"), **all_modules("firmware_py"), **all_modules("plant_sim")}
    hil = {m: p for m, p in known.items() if m == "hil" or m.startswith("hil.")}
    return hil, {m: {t for t in imports_of(p, m, known) if t in hil} for m, p in hil.items()}


def upward_imports(hil: dict[str, Path], graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for importer, targets in sorted(graph.items()):
        for target in sorted(targets):
            if target == "hil" or (importer, target) in ALLOWED_UPWARD:
                continue
            if layer_of(target) > layer_of(importer):
                bad.append(f"{hil[importer].relative_to(ROOT)} imports {hil[target].relative_to(ROOT)} "
                           f"(layer {layer_of(importer)} -> {layer_of(target)})")
    return bad


def circles(hil: dict[str, Path], graph: dict[str, set[str]]) -> list[str]:
    """Every import circle, as the files of one arrow in it (Tarjan's strongly connected components)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    out = []
    for component in found:
        a = component[0]
        b = next(t for t in sorted(graph[a]) if t in component)
        out.append(f"{hil[a].relative_to(ROOT)} imports {hil[b].relative_to(ROOT)}, which leads back to it "
                   f"(circle: {', '.join(component)})")
    return out


def test_hil_imports_point_down_the_layers():
    hil, graph = hil_graph()
    bad = upward_imports(hil, graph)
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_hil_has_no_import_circles():
    """The registry lookup (ALLOWED_UPWARD) is a lookup by name at run time, not an import the module
    needs to load: it is left out of the circle check too."""
    hil, graph = hil_graph()
    graph = {m: {t for t in targets if (m, t) not in ALLOWED_UPWARD} for m, targets in graph.items()}
    bad = circles(hil, graph)
    assert not bad, "import circles:\n" + "\n".join(bad)


def test_the_layer_check_fails_on_an_upward_import_and_on_a_circle():
    """The checks above are not vacuous: an import of the CLI from the codec, of fault injection or the
    report from the runtime, and a circle between two modules are all caught, naming the files."""
    hil, graph = hil_graph()
    graph = {m: set(t) for m, t in graph.items()}
    graph["hil.can.codec"].add("hil.cli.main")
    graph["hil.runtime.lockstep"].add("hil.safety.injection")
    graph["hil.runtime.run"].add("hil.report.kpis")
    bad = upward_imports(hil, graph)
    assert any(b.startswith("hil/can/codec.py imports hil/cli/main.py") for b in bad)
    assert any(b.startswith("hil/runtime/lockstep.py imports hil/safety/injection.py") for b in bad)
    assert any(b.startswith("hil/runtime/run.py imports hil/report/kpis.py") for b in bad)
    graph = {m: set(t) for m, t in hil_graph()[1].items()}
    graph["hil.can.dbc"].add("hil.can.codec")          # codec imports dbc: now a circle
    assert any("hil/can/codec.py" in b and "hil/can/dbc.py" in b for b in circles(hil, graph))


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


OWN = ("hil", "firmware_py", "plant_sim")
LAZY = "# lazy:"


def unexplained_function_imports(source: str, name: str) -> list[str]:
    """Imports of railhil's own modules inside a function without a ``# lazy: ... ms`` line above them or
    above the run of import statements they close."""
    lines = source.splitlines()
    tree = ast.parse(source, filename=name)
    bad = []
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for holder in ast.walk(fn):
            body = getattr(holder, "body", None)
            if not isinstance(body, list):
                continue
            explained = False
            for i, st in enumerate(body):
                if not isinstance(st, (ast.Import, ast.ImportFrom)):
                    explained = False
                    continue
                above = lines[st.lineno - 2].strip() if st.lineno > 1 else ""
                starts_run = i == 0 or not isinstance(body[i - 1], (ast.Import, ast.ImportFrom))
                if above.startswith(LAZY):
                    explained = " ms" in above
                elif starts_run:
                    explained = False
                modules = ([a.name for a in st.names] if isinstance(st, ast.Import)
                           else [st.module or ""] if st.level == 0 else ["." * st.level])
                if not explained and any(m.split(".")[0] in OWN or m.startswith(".") for m in modules):
                    bad.append(f"{name}:{st.lineno}: {ast.unparse(st)} inside {fn.name}() with no "
                               f"'{LAZY} <reason>, N ms' line above it")
    return bad


def test_own_modules_are_imported_at_module_level_unless_a_measured_cost_says_why():
    bad = []
    for package in OWN:
        for path in sorted((ROOT / package).rglob("*.py")):
            bad += unexplained_function_imports(path.read_text(), str(path.relative_to(ROOT)))
    assert not bad, "imports inside functions (move them to the top, or give the measured reason):\n" + \
        "\n".join(bad)


def test_the_function_import_check_fails_on_an_unexplained_import():
    source = """
def plain():
    from hil.can.codec import Codec
    return Codec


def explained():
    # lazy: keeps `railhil x --help` at 40 ms, not 400 ms
    from hil.report.html import write_report
    from hil.report.run import finish_run
    return write_report, finish_run


def no_figure():
    # lazy: because
    from hil.report.html import write_report
    return write_report


def second_run():
    # lazy: keeps it light, 400 ms
    from hil.report.html import write_report
    x = 1
    from hil.report.run import finish_run
    import json
    return x, write_report, finish_run, json
"""
    bad = unexplained_function_imports(source, "m.py")
    assert [b.split(":")[1] for b in bad] == ["3", "16", "24"], bad


@pytest.mark.parametrize("command, heavy", [
    ("wsp-test", "hil.campaign.sweep"), ("campaign", "hil.campaign.sweep"), ("report", "hil.report.html"),
    ("export-fmu", "hil.fmi.export"),
])
def test_the_lazy_imports_keep_their_commands_help_light(command, heavy):
    """The reason the `# lazy:` lines of these subcommands give holds: their --help loads no runner."""
    code = ("import sys; from hil.cli.main import main\n"
            f"try:\n    main([{command!r}, '--help'])\nexcept SystemExit:\n    pass\n"
            f"print({heavy!r} in sys.modules, 'numba' in sys.modules, file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.stderr.splitlines()[-1] == "False False", proc.stderr[-500:]


@pytest.mark.parametrize("module, heavy", [("hil.pytest_plugin", "hil.report.run"),
                                           ("hil", "hil.report.runfolder")])
def test_the_lazy_imports_keep_what_every_session_loads_light(module, heavy):
    """The pytest plugin (loaded by every pytest session) and `import hil` load no run machinery."""
    code = f"import sys, {module}; print({heavy!r} in sys.modules, 'numba' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.stdout.split() == ["False", "False"], proc.stderr[-500:]
