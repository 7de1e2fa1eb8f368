"""The command-line names of railhil 0.1 that still work, for one release (until railhil 0.3), and the
names they stand for today.  Each use prints one `notice:` line with the new name."""

from __future__ import annotations

import sys

UNTIL = "0.3"

#: `railhil reproduce OLD` -> the study's command-line name
REPRODUCE = {"picasso": "preview-slip", "acd": "anticollision"}

#: `railhil timing --function OLD` -> the DBC attribute RailhilFunction's value today
FUNCTIONS = {"seed000_preview": "preview_slip", "seed002_acd": "anticollision",
             "seed002_precise_stop": "precise_stop", "seed003_consensus": "consensus",
             "track_balises": "balises"}


def notice(old: str, new: str, what: str) -> None:
    print(f"notice: {what} {old!r} is now {new!r}; the old name works until railhil {UNTIL}", file=sys.stderr)


def function_names(names: list[str]) -> list[str]:
    """`--function` values with the old names replaced (a notice each)."""
    out = []
    for name in names:
        if name in FUNCTIONS:
            notice(name, FUNCTIONS[name], "--function")
            name = FUNCTIONS[name]
        out.append(name)
    return out
