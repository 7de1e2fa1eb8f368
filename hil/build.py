"""Which build of railhil runs: the hot modules compiled by mypyc, or all of it as pure Python.

`COMPILED` lists the modules setup.py compiles with mypyc when the package is built (``pip install``,
``make``'s install); the same files are the ones ``mypy`` checks strictly (pyproject.toml [tool.mypy],
tests/test_build.py). Each compiled module is an extension beside its ``.py``, and Python's import system
prefers the extension. The build also writes ``hil/_build.json``: the compiler's version and the SHA-256 of
each source it compiled.

At ``import hil`` (before any of these modules is imported), `choose` decides, once per process:

* ``RAILHIL_PURE=1`` in the environment: every module runs from its ``.py``;
* a source that changed since the build compiled it (an edit, a ``git checkout``): every module runs from
  its ``.py`` and one warning line names the file -- a stale extension never shadows an edited source;
  ``make`` rebuilds (``make build``);
* otherwise the compiled modules run (none when the install was built without a C compiler, with
  ``RAILHIL_PURE=1`` at build time, or never built: a plain checkout on ``PYTHONPATH``).

All or nothing: a compiled module calls the classes of the others natively, so a mix of compiled and pure
modules is never run. `state()` says which build runs and why (``railhil --version``, run.json).

Standard library only: setup.py reads `COMPILED` from this file without importing hil.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import json
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

#: the modules compiled by mypyc, as paths from the repository root (setup.py, [tool.mypy] files)
COMPILED: tuple[str, ...] = (
    "firmware_py/acd.py",
    "firmware_py/bcu.py",
    "firmware_py/becu.py",
    "firmware_py/brake_valve.py",
    "firmware_py/consensus.py",
    "firmware_py/constants.py",
    "firmware_py/cycle.py",
    "firmware_py/decel_feedback.py",
    "firmware_py/ekf.py",
    "firmware_py/governor.py",
    "firmware_py/limits.py",
    "firmware_py/pi.py",
    "firmware_py/preview.py",
    "firmware_py/reference_speed.py",
    "firmware_py/rx.py",
    "firmware_py/sensor_checks.py",
    "firmware_py/slipctl.py",
    "firmware_py/stopping.py",
    "firmware_py/wsp.py",
    "hil/can/bustiming.py",
    "hil/can/e2e.py",
    "hil/can/secoc.py",
    "hil/runtime/lockstep.py",
    "hil/runtime/node.py",
    "hil/runtime/plant_node.py",
    "hil/runtime/release.py",
)

PURE_ENV = "RAILHIL_PURE"               # set (to anything but "" or "0"): run pure Python
MANIFEST = "_build.json"                # beside this file, written by setup.py
ROOT = Path(__file__).resolve().parents[1]


def module_name(path: str) -> str:
    """firmware_py/becu.py -> firmware_py.becu"""
    return path.removesuffix(".py").replace("/", ".")


def source_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def extension_of(source: Path) -> Path | None:
    """The compiled module beside `source` (becu.cpython-311-x86_64-linux-gnu.so), if there is one."""
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        candidate = source.with_name(source.stem + suffix)
        if candidate.exists():
            return candidate
    return None


@dataclass(frozen=True)
class BuildState:
    """Which build runs: "compiled" (the modules of COMPILED from their extensions) or "pure"."""

    mode: str
    reason: str                          # why pure; what compiled them when compiled
    modules: tuple[str, ...]             # the modules that run compiled

    def line(self) -> str:
        if self.mode == "compiled":
            return f"compiled ({len(self.modules)} modules, {self.reason})"
        return f"pure Python ({self.reason})"

    def as_dict(self) -> dict[str, object]:
        return {"mode": self.mode, "reason": self.reason, "compiled_modules": list(self.modules)}


class _SourcesFirst(importlib.abc.MetaPathFinder):
    """Finds the modules of COMPILED from their .py files, ahead of the extension finder."""

    def __init__(self, names: set[str]) -> None:
        self.names = names

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in self.names:
            return None
        source = ROOT / (fullname.replace(".", "/") + ".py")
        return importlib.util.spec_from_file_location(fullname, source)


_state: BuildState | None = None


def read_manifest(root: Path = ROOT) -> dict | None:
    """hil/_build.json as the build wrote it, or None (never built)."""
    try:
        return json.loads((root / "hil" / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def decide(root: Path, manifest: dict | None, asked: str) -> BuildState:
    """The build to run for the sources under `root`, the build's `manifest` and RAILHIL_PURE's value."""
    present = [p for p in COMPILED if extension_of(root / p) is not None]
    if not present:
        why = manifest.get("pure_reason") if manifest else None
        return BuildState("pure", why or "not compiled: no compiled modules beside the sources", ())
    if asked not in ("", "0"):
        return BuildState("pure", f"{PURE_ENV}=1" if asked == "1" else asked, ())   # or a parent's reason
    digests = (manifest or {}).get("sources", {})
    stale = [p for p in COMPILED if digests.get(p) != source_digest(root / p)]
    if stale:
        more = f" (and {len(stale) - 1} more)" if len(stale) > 1 else ""
        return BuildState("pure", f"{stale[0]} changed since the build compiled it{more}: `make build` "
                                  "compiles again", ())
    if len(present) < len(COMPILED):
        missing = next(p for p in COMPILED if p not in present)
        return BuildState("pure", f"{missing} has no compiled module: `make build` compiles again", ())
    return BuildState("compiled", f"mypyc {manifest.get('mypyc', '?') if manifest else '?'}",
                      tuple(module_name(p) for p in COMPILED))


def choose() -> BuildState:
    """Decide which build this process runs (once; before any module of COMPILED is imported)."""
    global _state
    if _state is not None:
        return _state
    _state = decide(ROOT, read_manifest(), os.environ.get(PURE_ENV, ""))
    if _state.mode == "pure" and any(extension_of(ROOT / p) for p in COMPILED):
        names = {module_name(p) for p in COMPILED}
        loaded = sorted(n for n in names if n in sys.modules)
        if loaded:
            warnings.warn(f"{loaded[0]} was imported before hil: it runs compiled, the rest pure",
                          RuntimeWarning, stacklevel=2)
        sys.meta_path.insert(0, _SourcesFirst(names))
        if os.environ.get(PURE_ENV, "") in ("", "0"):       # stale: say so once, and children inherit
            print(f"warning: railhil runs pure Python: {_state.reason}", file=sys.stderr)
            os.environ[PURE_ENV] = _state.reason
    return _state


def state() -> BuildState:
    return choose()
