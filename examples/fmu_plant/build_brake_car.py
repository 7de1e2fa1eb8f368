"""Build brake_car.fmu: the one-car brake plant of brake_car/ (C, FMI 2.0 co-simulation) as an FMU with
its sources and a binary for this platform.

    .venv/bin/python examples/fmu_plant/build_brake_car.py                 # ./brake_car.fmu
    .venv/bin/python examples/fmu_plant/build_brake_car.py -o /tmp/plant.fmu
    .venv/bin/python examples/fmu_plant/build_brake_car.py --source-only   # sources only, no compiler needed

The source tree is zipped into a source FMU (modelDescription.xml, sources/), which FMPy then compiles as
`fmpy compile` does: extracted, built by `fmpy.build.build_platform_binary` (CMake and the C compiler,
FMPy's CMakeLists.txt and FMI 2.0 headers) into binaries/<platform>/, zipped again.  Needs cmake and a C
compiler on PATH (and a C++ compiler: FMPy's CMakeLists.txt enables C++ too); without them it says which
is missing and exits 2.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import traceback
import zipfile
from pathlib import Path

SOURCE_TREE = Path(__file__).resolve().parent / "brake_car"
MODEL_IDENTIFIER = "brake_car"
C_COMPILERS = ("cc", "gcc", "clang")        # CMake's own search order on Unix starts with cc, then gcc
CXX_COMPILERS = ("c++", "g++", "clang++")   # FMPy's CMakeLists.txt declares project() without LANGUAGES C,
#                                             so CMake enables C++ too and stops without a C++ compiler


class BuildToolMissing(RuntimeError):
    """cmake or a C (or C++) compiler is not on PATH."""


def _compiler_found(env_var: str, names: tuple[str, ...]) -> bool:
    chosen = os.environ.get(env_var)
    if chosen:                                      # CMake takes $CC / $CXX when set
        return shutil.which(chosen) is not None
    return any(shutil.which(name) for name in names)


def missing_build_tools() -> list[str]:
    """What of cmake and the compilers cannot be found ([] = the FMU can be built)."""
    missing = []
    if shutil.which("cmake") is None:
        missing.append("cmake")
    if not _compiler_found("CC", C_COMPILERS):
        missing.append(f"a C compiler ({os.environ.get('CC') or ' / '.join(C_COMPILERS)})")
    if not _compiler_found("CXX", CXX_COMPILERS):
        missing.append(f"a C++ compiler ({os.environ.get('CXX') or ' / '.join(CXX_COMPILERS)}; FMPy's "
                       "CMakeLists.txt enables C++ although the FMU is C)")
    return missing


def _zip_tree(folder: Path, out: Path) -> None:
    """Every file below `folder` into the zip `out`, paths relative to it with forward slashes, in sorted
    order and with a fixed time stamp: the same tree gives the same bytes."""
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            info = zipfile.ZipInfo(path.relative_to(folder).as_posix(), date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, path.read_bytes())


def write_source_fmu(out: Path) -> Path:
    """The source FMU (modelDescription.xml, sources/, no binary) written to `out`; returns `out`."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="brake_car-src-") as tmp:
        tree = Path(tmp) / "fmu"
        shutil.copytree(SOURCE_TREE, tree, ignore=shutil.ignore_patterns("*~", ".*", "__pycache__"))
        _zip_tree(tree, out)
    return out


def build_brake_car(out: Path) -> Path:
    """The FMU with its sources and a binary for this platform written to `out`; returns `out`.

    Raises BuildToolMissing without cmake or a compiler, subprocess.CalledProcessError when CMake fails.
    """
    from fmpy import extract
    from fmpy.build import build_platform_binary

    missing = missing_build_tools()
    if missing:
        raise BuildToolMissing(f"cannot compile brake_car.fmu, not found on PATH: {', '.join(missing)}")
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="brake_car-build-") as tmp:
        source_fmu = write_source_fmu(Path(tmp) / "brake_car-source.fmu")
        unzipdir = Path(extract(str(source_fmu), unzipdir=str(Path(tmp) / "fmu")))
        build_dir = Path(tmp) / "cmake"
        build_dir.mkdir()
        build_platform_binary(unzipdir, build_dir=build_dir, configuration="Release", all_warnings=True)
        binary = unzipdir / "binaries"
        if not any(binary.rglob(MODEL_IDENTIFIER + ".*")):
            raise RuntimeError(f"CMake ran but left no {MODEL_IDENTIFIER} library under {binary}")
        out.parent.mkdir(parents=True, exist_ok=True)
        _zip_tree(unzipdir, out)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--output", type=Path, default=Path("brake_car.fmu"), metavar="OUT.fmu",
                        help="the FMU to write (default: brake_car.fmu in the current folder)")
    parser.add_argument("--source-only", action="store_true",
                        help="write the source FMU only (no binary, no compiler needed)")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    args = parser.parse_args(argv)
    try:
        if args.source_only:
            path = write_source_fmu(args.output)
        else:
            path = build_brake_car(args.output)
    except BuildToolMissing as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except subprocess.CalledProcessError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"error: CMake failed building brake_car (exit {exc.returncode}); its output is above",
              file=sys.stderr)
        return 1
    except Exception as exc:   # the CLI's one-line error; --debug shows the traceback
        if args.debug:
            traceback.print_exc()
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {path.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
