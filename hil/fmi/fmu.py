"""An FMU opened for co-simulation by FMPy: checked as it is opened, stepped on the bench's clock.

`open_fmu(path)` reads the model description and refuses, in one line each (FmuError, exit 2), a file that
is not an FMU, an FMU without co-simulation, one without a binary for this platform; `CoSimulation` then
instantiates it, sets start values, steps it and reads and writes its variables by name.  FMI 2.0 and
FMI 3.0 both: the bench sees numbers (reals and integers, booleans and enumerations as integers).

FMPy imports and steps FMUs in a loop of one's own, which is what the bench is: the plant node steps its
FMU at the plant's step, a node at its cycle, on the bench's integer clock (lockstep) or the wall clock
(real time).  The FMU's own time starts at 0 and advances by exactly the steps the bench asks for.
"""

from __future__ import annotations

import contextlib
import difflib
import math
import shutil
import weakref
import zipfile
from collections.abc import Iterator, Sequence
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

from hil.errors import FmuError

#: the FMI types the bench reads as floats, and those it reads as integers (booleans and enumerations too)
REAL_TYPES = frozenset({"Real", "Float64", "Float32"})
INTEGER_TYPES = frozenset({"Integer", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64",
                           "UInt64", "Enumeration", "Boolean"})


@dataclass(frozen=True)
class Variable:
    """One scalar variable of an FMU as the bench uses it."""

    name: str
    vr: int                     # value reference
    type: str                   # FMI type name: Real, Integer, Boolean, Enumeration (2.0); Float64, ... (3.0)
    causality: str              # input, output, parameter, local, calculatedParameter, independent, ...
    variability: str | None
    unit: str | None            # its declared unit (None: a pure number)
    description: str
    start: float | None


@dataclass(frozen=True)
class FmuInfo:
    """What the model description says, as the bench needs it."""

    path: Path
    fmi_version: str            # "2.0", "3.0"
    model_name: str
    model_identifier: str       # of the co-simulation interface
    guid: str
    variables: dict[str, Variable]
    step_size_s: float | None   # DefaultExperiment stepSize
    variable_step: bool         # canHandleVariableCommunicationStepSize
    generation_tool: str


def _variables(md) -> dict[str, Variable]:
    out = {}
    for v in md.modelVariables:
        if getattr(v, "dimensions", None):              # FMI 3.0 arrays: not carried
            continue
        unit = v.unit
        if unit is None and v.declaredType is not None:
            unit = getattr(v.declaredType, "unit", None)
        start = None
        if v.start not in (None, ""):
            try:
                start = float({"true": 1, "false": 0}.get(str(v.start).lower(), v.start))
            except (TypeError, ValueError):
                start = None
        out[v.name] = Variable(v.name, int(v.valueReference), v.type, v.causality, v.variability,
                               unit or None, v.description or "", start)
    return out


def open_fmu(path: str | Path) -> FmuInfo:
    """The FMU at `path`, checked: a zip with a readable modelDescription.xml, FMI 2.0 or 3.0, with
    co-simulation and a binary for this platform.  An FmuError naming the file and what is missing."""
    import fmpy
    from fmpy.model_description import read_model_description

    path = Path(path)
    if not path.is_file():
        raise FmuError(f"{path}: no such FMU file")
    if not zipfile.is_zipfile(path):
        raise FmuError(f"{path}: not an FMU (an FMU is a zip archive with a modelDescription.xml; this file "
                       "is not a zip archive)")
    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
    if "modelDescription.xml" not in names:
        raise FmuError(f"{path}: not an FMU: the archive has no modelDescription.xml")
    try:
        md = read_model_description(str(path), validate=False)
    except Exception as exc:   # noqa: BLE001 - FMPy raises many kinds for a bad description
        raise FmuError(f"{path}: modelDescription.xml does not read: {_first_line(exc)}") from None
    if md.fmiVersion not in ("2.0", "3.0"):
        raise FmuError(f"{path}: FMI {md.fmiVersion}: the bench runs FMI 2.0 and 3.0 co-simulation FMUs")
    if md.coSimulation is None:
        kinds = [k for k, t in (("model exchange", md.modelExchange),
                                ("scheduled execution", getattr(md, "scheduledExecution", None))) if t]
        raise FmuError(f"{path}: FMU {md.modelName!r} has no co-simulation interface (it offers "
                       f"{' and '.join(kinds) or 'none'}); export it from its tool as co-simulation "
                       "(with its own solver)")
    identifier = md.coSimulation.modelIdentifier
    platform = fmpy.platform if md.fmiVersion == "2.0" else fmpy.platform_tuple
    binary = f"binaries/{platform}/{identifier}{fmpy.sharedLibraryExtension}"
    if binary not in names:
        built = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
        sources = any(n.startswith("sources/") for n in names)
        hint = ("; it has C sources: build the binary with `fmpy compile FMU` (a C compiler and CMake)"
                if sources else "; export it for this platform from its tool")
        raise FmuError(f"{path}: FMU {md.modelName!r} has no binary for this platform ({binary} is missing; "
                       f"it has {', '.join(built) or 'none'}){hint}")
    experiment = md.defaultExperiment
    step = None
    if experiment is not None and experiment.stepSize not in (None, ""):
        step = float(experiment.stepSize)
    return FmuInfo(path, md.fmiVersion, md.modelName, identifier, md.guid, _variables(md), step,
                   bool(md.coSimulation.canHandleVariableCommunicationStepSize),
                   md.generationTool or "")


_CHECK_ONLY: ContextVar[bool] = ContextVar("railhil_fmu_check_only", default=False)


@contextlib.contextmanager
def check_only() -> Iterator[None]:
    """FMUs built in this block are opened, checked and wired but not instantiated: the real-time runner's
    check of every node before it forks their processes.  An FMU's library loaded in the parent would be
    inherited half-alive by the fork (PythonFMU's crashes the child on its next instance)."""
    token = _CHECK_ONLY.set(True)
    try:
        yield
    finally:
        _CHECK_ONLY.reset(token)


def checking_only() -> bool:
    return _CHECK_ONLY.get()


def scenario_fmus(scenario) -> dict[str, str]:
    """The FMUs a scenario runs, by the node they are: {"PLANT": path, "BECU3": path}."""
    out = {"PLANT": scenario.plant.fmu} if scenario.plant.fmu else {}
    out.update({name: t.fmu for name, t in scenario.nodes.items() if t.fmu})
    return out


def describe(path: str | Path) -> dict:
    """What run.json keeps of an FMU: its file and SHA-256, model, FMI version and the tool that made it."""
    import hashlib

    info = open_fmu(path)
    return {"file": str(info.path), "sha256": hashlib.sha256(info.path.read_bytes()).hexdigest(),
            "model": info.model_name, "fmi": info.fmi_version, "generation_tool": info.generation_tool}


def closest(name: str, names: Sequence[str]) -> str:
    """'; closest: a, b' for a name not found among `names`."""
    close = difflib.get_close_matches(name, list(names), n=3, cutoff=0.5)
    return f"; closest: {', '.join(close)}" if close else ""


def validation_problems(path: str | Path) -> list[str]:
    """FMPy's own validation of the FMU (fmpy.validation.validate_fmu): the problems it lists."""
    from fmpy.validation import validate_fmu

    return list(validate_fmu(str(path)))


def refs(info: FmuInfo, names: Sequence[str]) -> tuple[list[int], list[int], list[int], list[int]]:
    """(positions of reals, their value references, positions of integers, theirs) for `names`: what
    `CoSimulation.set` and `get` take, made once."""
    real_at, real_vr, int_at, int_vr = [], [], [], []
    for k, name in enumerate(names):
        v = info.variables[name]
        if v.type in REAL_TYPES:
            real_at.append(k)
            real_vr.append(v.vr)
        else:
            int_at.append(k)
            int_vr.append(v.vr)
    return real_at, real_vr, int_at, int_vr


def _first_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 140 else text[:137] + "..."


class CoSimulation:
    """One instance of an FMU, stepped by the bench: `set(refs, values)`, `step(h)`, `get(refs, n)`.

    Variables go by value reference in groups made once (`refs(info, names)`), so a step costs one call per
    type.  `start` values (parameters, start values of inputs and states) are set before initialisation."""

    def __init__(self, info: FmuInfo, instance_name: str, start: dict[str, float] | None = None) -> None:
        from fmpy import extract
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave

        self.info = info
        self.unzip_dir = extract(str(info.path))
        # the extracted FMU goes with this object, or at exit: a campaign builds many (the library stays
        # mapped, a deleted file is no matter to it)
        self._cleanup = weakref.finalize(self, shutil.rmtree, self.unzip_dir, True)
        cls = FMU2Slave if info.fmi_version == "2.0" else FMU3Slave
        self.t_s = 0.0
        try:
            self.fmu = cls(guid=info.guid, unzipDirectory=self.unzip_dir,
                           modelIdentifier=info.model_identifier, instanceName=instance_name)
            v3 = info.fmi_version == "3.0"
            self._get_real = self.fmu.getFloat64 if v3 else self.fmu.getReal
            self._set_real = self.fmu.setFloat64 if v3 else self.fmu.setReal
            self._get_int = self.fmu.getInt32 if v3 else self.fmu.getInteger
            self._set_int = self.fmu.setInt32 if v3 else self.fmu.setInteger
            self.fmu.instantiate()
            if not v3:
                self.fmu.setupExperiment(startTime=0.0)
            if start:
                self.set(refs(info, list(start)), list(start.values()))
            self.fmu.enterInitializationMode()
            self.fmu.exitInitializationMode()
        except Exception as exc:   # noqa: BLE001 - an FMU's own failure (fmi2Error), or its library's
            self.close()
            raise FmuError(f"{info.path}: FMU {info.model_name!r} did not initialise: {_first_line(exc)}") \
                from None

    def set(self, refs, values: Sequence[float]) -> None:
        """Write `values` (in the order of the names `refs` was made from)."""
        real_at, real_vr, int_at, int_vr = refs
        if real_vr:
            self._set_real(real_vr, [float(values[k]) for k in real_at])
        if int_vr:
            self._set_int(int_vr, [_as_int(values[k]) for k in int_at])

    def get(self, refs, n: int) -> list[float]:
        """The values of the `n` names `refs` was made from, as floats."""
        real_at, real_vr, int_at, int_vr = refs
        out = [0.0] * n
        if real_vr:
            for k, value in zip(real_at, self._get_real(real_vr), strict=True):
                out[k] = value
        if int_vr:
            for k, value in zip(int_at, self._get_int(int_vr), strict=True):
                out[k] = float(value)
        return out

    def step(self, h_s: float, t_s: float | None = None) -> None:
        """Advance the FMU from its time (`t_s` where the caller keeps it exactly) by `h_s` seconds
        (fmi2DoStep / fmi3DoStep)."""
        if t_s is not None:
            self.t_s = t_s
        try:
            self.fmu.doStep(currentCommunicationPoint=self.t_s, communicationStepSize=h_s)
        except Exception as exc:   # noqa: BLE001 - fmi2Error / fmi2Discard from the FMU
            raise FmuError(f"{self.info.path}: FMU {self.info.model_name!r} failed its step at t = "
                           f"{self.t_s:.6f} s: {_first_line(exc)}") from None
        self.t_s += h_s

    def close(self) -> None:
        fmu = getattr(self, "fmu", None)
        if fmu is not None:
            try:
                fmu.terminate()
                fmu.freeInstance()
            except Exception:   # noqa: BLE001, S110 - closing an FMU that failed: nothing more to do
                pass
            self.fmu = None
        self._cleanup()


def _as_int(value: float) -> int:
    """An integer input's value: a float from the bus rounded; NaN or infinite as 0 (the FMU's safe state is
    its own affair, but it gets a number)."""
    return int(round(value)) if math.isfinite(value) else 0
