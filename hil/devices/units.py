"""Unit conversions of a device map, from the DBCs' unit strings, by pint.

A DBC writes units as text ("km/h", "bar", "m/s^2", "rpm", "%", "Nm"); pint reads them (km/h and m/s are
speeds, bar and Pa pressures, rpm and rad/s angular speeds, % a fraction).  `affine` turns one map entry's
conversion — the source's unit to the target's, times a scale that may carry a unit of its own ("0.46 m":
a wheel radius turns rad/s into m/s), plus an offset — into the two numbers y = a·x + b that the gateway
applies to every value, so pint is asked once per entry, when the map is loaded, and never per frame.

Spellings pint reads otherwise than a DBC means them are rewritten first (`DBC_SPELLINGS`: "Nm" is a
newton metre in a DBC, a nanometre... nowhere pint would guess it).  A DBC signal without a unit is a pure
number (dimensionless).
"""

from __future__ import annotations

import functools
import math

from hil.errors import DeviceError

#: DBC unit spellings that pint would read otherwise (or not at all) -> what they mean
DBC_SPELLINGS = {"Nm": "N*m", "kmh": "km/h", "km/hr": "km/h", "°": "deg", "°C": "degC", "1/min": "rpm",
                 "U/min": "rpm", "mps": "m/s"}


@functools.cache
def registry():
    """pint's unit registry, built on first use (0.1 s): only a run with a device needs it."""
    import pint

    return pint.UnitRegistry(autoconvert_offset_to_baseunit=False)


def _spelled(text: str) -> str:
    text = text.strip()
    return DBC_SPELLINGS.get(text, text)


def unit_of(text: str | None, where: str):
    """The pint unit of a unit string (None or "": dimensionless); a DeviceError naming `where` if pint
    cannot read it."""
    import pint

    if text is None or not text.strip():
        return registry().dimensionless
    try:
        return registry().parse_units(_spelled(text))
    except (pint.errors.UndefinedUnitError, pint.errors.DefinitionSyntaxError, AttributeError, TypeError,
            ValueError, AssertionError) as exc:
        raise DeviceError(f"{where}: unit {text!r} is not a unit pint knows ({_first_line(exc)}); write it "
                          "as pint does, e.g. km/h, bar, m/s^2, rpm, %") from None


def quantity(value, where: str, unit: str | None = None):
    """A number (in `unit`) or a quantity text such as "0.46 m" or "40 t" as a pint Quantity."""
    import pint

    reg = registry()
    if isinstance(value, bool):
        raise DeviceError(f"{where}: {value!r} is not a number or a quantity")
    if isinstance(value, int | float):
        if not math.isfinite(value):
            raise DeviceError(f"{where}: {value!r} is not a finite number")
        return reg.Quantity(value, unit_of(unit, where))
    try:
        q = reg.Quantity(_spelled(str(value)))
    except (pint.errors.UndefinedUnitError, pint.errors.DefinitionSyntaxError, AttributeError, TypeError,
            ValueError, AssertionError) as exc:
        raise DeviceError(f"{where}: {value!r} is not a number or a quantity pint reads "
                          f"({_first_line(exc)}); e.g. 0.46 m, 40 t, 3.5 bar") from None
    if not isinstance(q, pint.Quantity):            # a bare number written as text
        q = reg.Quantity(float(q), reg.dimensionless)
    if not math.isfinite(float(q.magnitude)):
        raise DeviceError(f"{where}: {value!r} is not finite")
    return q


def _first_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= 100 else text[:97] + "..."


def _dimension(unit) -> str:
    dims = str(registry().Quantity(1, unit).dimensionality)
    return "a pure number" if dims == "dimensionless" else dims


def affine(src_unit: str | None, dst_unit: str | None, scale=1.0, offset=0.0, *, where: str,
           source: str = "the source", target: str = "the target") -> tuple[float, float]:
    """(a, b) with target = a·source + b: the source value in `src_unit`, times `scale` (a number or a
    quantity text), converted to `dst_unit`, plus `offset` (a number in `dst_unit`, or a quantity).  A
    DeviceError naming `where` when the units do not convert (with both dimensions)."""
    import pint

    src, dst = unit_of(src_unit, where), unit_of(dst_unit, where)
    factor = quantity(scale, f"{where}: scale")
    shift = quantity(offset, f"{where}: offset", dst_unit)
    reg = registry()

    def convert(x: float) -> float:
        q = reg.Quantity(x, src)
        if factor.unitless and factor.magnitude == 1:
            value = q.to(dst)                       # temperatures convert with their offsets
        else:
            value = (q * factor).to(dst)
        return float(value.magnitude) + float(shift.to(dst).magnitude)

    try:
        b = convert(0.0)
        a = convert(1.0) - b
    except pint.errors.DimensionalityError:
        joined = f"{src_unit or '(no unit)'}" + ("" if factor.unitless else f" × {factor.units:~}")
        raise DeviceError(f"{where}: cannot convert {source} [{joined}] to {target} "
                          f"[{dst_unit or '(no unit)'}]: {_dimension(src * factor.units)} is not "
                          f"{_dimension(dst)}; give the source's 'unit', or a 'scale' with the unit that "
                          "joins them (e.g. scale = \"0.46 m\" from rad/s to km/h)") from None
    except pint.errors.OffsetUnitCalculusError:
        raise DeviceError(f"{where}: {source} [{src_unit}] has an offset unit (a temperature): it takes no "
                          "'scale' with a unit") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise DeviceError(f"{where}: the conversion of {source} to {target} is not finite")
    return a, b


def magnitude_in(value, unit: str | None, where: str) -> float:
    """A constant (a number in `unit`, or a quantity text) as a number in `unit`."""
    import pint

    q = quantity(value, where, unit)
    try:
        return float(q.to(unit_of(unit, where)).magnitude)
    except pint.errors.DimensionalityError:
        raise DeviceError(f"{where}: {value!r} is {_dimension(q.units)}, the signal is in "
                          f"{unit or '(no unit)'} ({_dimension(unit_of(unit, where))})") from None
