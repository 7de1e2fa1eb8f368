"""Where the files railhil ships are: the DBC, the scenarios, the rail profiles, the campaigns and the test
programmes.

In a source checkout (and an editable install) they are the repository's folders `dbc/`, `scenarios/`,
`scenarios/profiles/`, `campaigns/` and `programmes/`.  A wheel carries the same folders as package data under
`hil/_data/` (pyproject.toml maps them there), so an installed railhil finds them from any directory.

A scenario may be named instead of given by path: `railhil run default` is the shipped
`scenarios/default.toml` (`resolve_scenario`).
"""

from __future__ import annotations

import difflib
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hil.errors import ScenarioError

_PACKAGED = Path(__file__).resolve().parent / "_data"     # installed from a wheel
_CHECKOUT = Path(__file__).resolve().parents[1]           # a source checkout


def data_root() -> Path:
    """The folder holding dbc/, scenarios/ and campaigns/."""
    return _PACKAGED if _PACKAGED.is_dir() else _CHECKOUT


def dbc_dir() -> Path:
    return data_root() / "dbc"


def scenarios_dir() -> Path:
    return data_root() / "scenarios"


def profiles_dir() -> Path:
    return scenarios_dir() / "profiles"


def campaigns_dir() -> Path:
    return data_root() / "campaigns"


def read_toml(path: Path, error: type[Exception], where: str,
              missing: str | Callable[[], str] = "no such file") -> dict:
    """The table of the TOML file `path`, or `error` with one line: "<where>: <missing>" when there is no
    such file (`missing` may be a function, called only then), "<where>: cannot read: ..." or
    "<where>: not valid TOML: ..." otherwise."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(f"{where}: {missing() if callable(missing) else missing}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{where}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{where}: not valid TOML: {exc}") from None


def programmes_dir() -> Path:
    """The test programmes (`railhil wsp-test`'s wsp_test.toml)."""
    return data_root() / "programmes"


DEFAULT_DBC_NAME = "train_brake.dbc"


def default_dbc() -> Path:
    """The train's CAN schema, dbc/train_brake.dbc."""
    return dbc_dir() / DEFAULT_DBC_NAME


@dataclass(frozen=True)
class ShippedScenario:
    name: str
    path: Path
    description: str


def shipped_scenarios() -> list[ShippedScenario]:
    """The scenarios railhil ships, by name, with the first line of each one's description."""
    out = []
    for path in sorted(scenarios_dir().glob("*.toml")):
        try:
            data = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError):
            data = {}
        text = " ".join(str(data.get("description", "")).split())
        out.append(ShippedScenario(path.stem, path, text))
    return out


def unknown_scenario(name: str) -> str:
    """What to say of a scenario name that is no shipped scenario: the closest shipped names (difflib, as
    for scenario keys and DBC names), else every shipped name."""
    names = [s.name for s in shipped_scenarios()]
    stem = Path(name).name.removesuffix(".toml")
    close = difflib.get_close_matches(stem, names, n=3, cutoff=0.6)
    if close:
        return (f"did you mean {' or '.join(close)}? (`railhil scenarios` describes the {len(names)} shipped "
                f"scenarios)")
    return f"shipped: {', '.join(names)}; `railhil scenarios` describes them"


def resolve_scenario(ref: str | Path) -> Path:
    """The scenario file `ref` names: a path that exists, else a shipped scenario's name (`default`,
    `default.toml`).  Neither: a ScenarioError with the closest shipped names (`unknown_scenario`)."""
    path = Path(ref)
    if path.exists():
        return path
    text = str(ref)
    if "/" not in text and "\\" not in text:
        shipped = scenarios_dir() / (text if text.endswith(".toml") else f"{text}.toml")
        if shipped.is_file():
            return shipped
    raise ScenarioError(f"{ref}: no such scenario file, and no shipped scenario of that name; "
                        f"{unknown_scenario(text)}")
