"""Progress bars: the one way railhil makes them.

A bar is tqdm's, on stderr, and only where a person watches it: tqdm's `disable=None` turns a bar off
when its stream is not a terminal, so `make bench > log`, a CI job or a pipe gets a command's results and
none of the carriage-return updates a bar redraws itself with.  A command's `-q` turns it off on a
terminal too.  tqdm is imported at the first bar, so a command that draws none does not load it.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from tqdm import tqdm


def progress_bar(total: float | None = None, *, enabled: bool = True, file: TextIO | None = None,
                 **options) -> tqdm:
    """A tqdm bar over `total` on `file` (default: stderr), drawn only when `enabled` and `file` is a
    terminal; otherwise a disabled bar (`.disable` true), whose `update`, `refresh` and `close` do
    nothing.  `options` are tqdm's (`desc`, `unit`, `leave`, `delay`, `bar_format`, ...)."""
    from tqdm import tqdm

    return tqdm(total=total, file=sys.stderr if file is None else file, disable=None if enabled else True,
                **options)
