"""python-can's MF4 support loaded when an MF4 file is first opened, not on `import can`.

`import can` imports `can.io.mf4`, which imports asammdf at once, and asammdf imports pandas and
canmatrix: 0.64 of the 0.77 s that `import can` takes on this machine (`python -X importtime -c
"import can"`), paid by every railhil process (each real-time host, each campaign worker, each CLI
command), though most never touch an MF4 file.  python-can knows it (hardbyte/python-can#935, "Slow
library import time", open).

`install()` (called by `hil/__init__.py`, so before any railhil module imports `can`) puts a finder on
`sys.meta_path` that changes one thing: while `can.io.mf4` is first executed, `import asammdf` fails,
so python-can takes its own "asammdf not installed" branch (its module-level names are None).  The
first `MF4Reader(...)` or `MF4Writer(...)` (or a subclass: hil.trace.writers.Mf4Writer) then runs
python-can's own `try:` block of imports — taken from can/io/mf4.py's source, not copied here — in the
module, and goes on as python-can would.  Where asammdf is really missing, that block fails as it would
have on import and python-can's own error follows.  Where can/io/mf4.py has no such block (another
python-can), or `can` is imported before `hil`, nothing is deferred.
"""

from __future__ import annotations

import ast
import functools
import importlib.abc
import importlib.machinery
import sys

MODULE = "can.io.mf4"
DEFERRED = "asammdf"


def _import_block(source: str) -> ast.Try | None:
    """The module-level `try:` whose body starts with `import asammdf` (python-can 4.x's mf4.py)."""
    for node in ast.parse(source).body:
        if isinstance(node, ast.Try) and node.body and isinstance(node.body[0], ast.Import) \
                and any(alias.name == DEFERRED for alias in node.body[0].names):
            return node
    return None


class _Refuse(importlib.abc.MetaPathFinder):
    """Makes `import asammdf` (and its submodules) fail while it is on sys.meta_path."""

    def find_spec(self, name, path, target=None):
        if name == DEFERRED or name.startswith(DEFERRED + "."):
            raise ModuleNotFoundError(f"No module named {name!r} (deferred by hil.can.lazy_mf4)", name=name)
        return None


class _DeferringLoader(importlib.abc.Loader):
    def __init__(self, loader, block: ast.Try, origin: str) -> None:
        self._loader, self._block, self._origin = loader, block, origin

    def __getattr__(self, name: str):
        return getattr(self._loader, name)             # get_source, get_code, …: python-can's file's

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        refuse = _Refuse()
        sys.meta_path.insert(0, refuse)
        try:
            self._loader.exec_module(module)
        finally:
            sys.meta_path.remove(refuse)
        if getattr(module, DEFERRED, True) is not None:
            return                                       # python-can loaded asammdf some other way
        imports = compile(ast.Module(body=self._block.body, type_ignores=[]), self._origin, "exec")
        done = False

        def complete() -> None:
            nonlocal done
            if not done:
                try:
                    exec(imports, vars(module))          # python-can's own imports, in its module
                except ImportError:
                    pass                                 # really missing: python-can raises its own error
                done = True

        for cls in (module.MF4Reader, module.MF4Writer):
            init = cls.__init__

            @functools.wraps(init)
            def __init__(self, *args, _init=init, **kwargs):
                complete()
                _init(self, *args, **kwargs)

            cls.__init__ = __init__


class _DeferFinder(importlib.abc.MetaPathFinder):
    """Hands `can.io.mf4` a loader that defers its asammdf imports (module docstring)."""

    def find_spec(self, name, path, target=None):
        if name != MODULE:
            return None
        sys.meta_path.remove(self)                       # once: this import only
        if DEFERRED in sys.modules:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.origin is None or not isinstance(spec.loader, importlib.abc.Loader):
            return None
        try:
            with open(spec.origin, encoding="utf-8") as f:
                block = _import_block(f.read())
        except (OSError, SyntaxError, ValueError):
            return None
        if block is None:
            return None
        spec.loader = _DeferringLoader(spec.loader, block, spec.origin)
        return spec


def install() -> None:
    """Defer asammdf in `can.io.mf4` if `can` is not imported yet (idempotent)."""
    if MODULE in sys.modules or any(isinstance(f, _DeferFinder) for f in sys.meta_path):
        return
    sys.meta_path.insert(0, _DeferFinder())
