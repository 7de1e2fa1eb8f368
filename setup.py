"""railhil's build: the hot modules (hil/build.py COMPILED) compiled with mypyc, or all pure Python.

Compiled when mypyc (pinned in pyproject.toml [build-system]) and a C compiler are there and RAILHIL_PURE is
not set; otherwise pure, and the install still works. Either way hil/_build.json records what was built and
the SHA-256 of each compiled source, so that `import hil` notices a source edited since (hil.build).
"""

import json
import os
import runpy
import shutil
import sys
import sysconfig
from pathlib import Path

from setuptools import setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
build = runpy.run_path(str(HERE / "hil" / "build.py"))     # stdlib only: hil itself is not importable here
COMPILED = list(build["COMPILED"])
MANIFEST = HERE / "hil" / build["MANIFEST"]


def pure_reason() -> str | None:
    """Why this build stays pure Python, or None to compile."""
    asked = os.environ.get(build["PURE_ENV"], "")
    if asked not in ("", "0"):
        return f"built with {build['PURE_ENV']}={asked}"
    compiler = (os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(compiler) is None:
        return f"built without a C compiler ({compiler} not found)"
    try:
        import mypyc  # noqa: F401
    except ImportError:
        return "built without mypyc"
    return None


def manifest(**fields) -> dict:
    from importlib.metadata import version
    try:
        mypyc_version = version("mypy")
    except Exception:
        mypyc_version = None
    return {"mypyc": mypyc_version, "python": sys.version.split()[0],
            "sources": {p: build["source_digest"](HERE / p) for p in COMPILED}, **fields}


def write_manifest(data: dict, build_lib: str | None) -> None:
    """hil/_build.json into the wheel's tree, or beside the sources in a development (in-place) build."""
    path = MANIFEST if build_lib is None else Path(build_lib) / "hil" / MANIFEST.name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")


class BuildPyWithManifest(build_py):
    def run(self) -> None:
        super().run()
        write_manifest(MANIFEST_DATA, None if self.editable_mode else self.build_lib)


class BuildExtOrPure(build_ext):
    """A failed compile leaves a pure build that says why, not a failed install.  The extensions (mypyc's
    shared library of every compiled module, and a small one that imports it for each module) are compiled
    on every core, unless `build_ext --parallel N` says otherwise."""

    def finalize_options(self) -> None:
        super().finalize_options()
        if self.parallel is None:
            self.parallel = os.cpu_count() or 1

    def run(self) -> None:
        try:
            super().run()
        except Exception as exc:                         # the compiler's error, e.g. a missing Python.h
            print(f"warning: railhil's mypyc compile failed, installing pure Python: {exc}", file=sys.stderr)
            write_manifest(manifest(pure_reason=f"the compile failed: {exc}"),
                           None if self.inplace else self.build_lib)


# mypyc's own type check: the modules' strictness is make test's (mypy --strict, every dependency there);
# a build without some dependency's types (pip's isolated build) reads them as Any and still compiles
LENIENT = ["--ignore-missing-imports", "--no-warn-unused-ignores", "--no-warn-return-any",
           "--allow-subclassing-any", "--allow-untyped-calls", "--allow-untyped-decorators"]

# pip asks for the package's metadata in calls of their own (`setup.py egg_info`, `dist_info`) before the
# call that builds (editable_wheel, bdist_wheel, build_ext): mypyc's type check and C generation (about 40 s)
# run in that one only
command = next((arg for arg in sys.argv[1:] if not arg.startswith("-")), None)
METADATA_ONLY = command in ("egg_info", "dist_info")

reason = pure_reason()
if reason is None and METADATA_ONLY:
    ext_modules = []
elif reason is None:
    from mypyc.build import mypycify

    try:
        ext_modules = mypycify([*LENIENT, *COMPILED], opt_level="3", debug_level="0")
    except (Exception, SystemExit) as exc:      # a type error mypyc will not compile: printed above
        reason = f"the compile failed: mypyc's type check ({exc!r})"
if reason is None:
    MANIFEST_DATA = manifest()
else:
    print(f"railhil: {reason}: installing pure Python", file=sys.stderr)
    ext_modules = []
    MANIFEST_DATA = manifest(pure_reason=reason)

setup(ext_modules=ext_modules, cmdclass={"build_ext": BuildExtOrPure, "build_py": BuildPyWithManifest})
