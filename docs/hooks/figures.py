"""`make docs-figures`: the figures and printed outputs of the docs, made again by the code as it is now.

Not a MkDocs hook (it sits beside them, outside the site): run it after a change that changes what a run
prints or draws, then review the diff and commit it with the change.

* A lockstep run of the default scenario (deterministic: the same figures on every machine, but for the
  wall time): `docs/img/plot.png`; every console block of README.md and docs/*.md that shows
  `$ railhil run scenarios/default.toml --lockstep --out /tmp/tour` gets that run's output (its folder
  written as /tmp/tour); docs/reports.md's `kpis.json` block that run's kpis.json.
* A real-time run of it, `make run`'s command (lockstep where the bus cannot be opened): the block between
  the `make docs-figures: make run` markers of docs/getting-started.md gets its output, and
  `docs/img/report.png` its report.html's first screen at 1,280 px in headless Chromium (none where no
  Chromium is installed: it says so).

tests/test_first_hour.py checks the lockstep figures and plot.png against a fresh run, with the functions
below.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOUR = "/tmp/tour"                                  # the run folder the docs show
LOCKSTEP_COMMAND = f"railhil run scenarios/default.toml --lockstep --out {TOUR}"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PLOT = ROOT / "docs" / "img" / "plot.png"
SCREENSHOT = ROOT / "docs" / "img" / "report.png"
REALTIME_MARK = ("<!-- make docs-figures: make run -->", "<!-- /make docs-figures -->")
KPIS_DOC = ROOT / "docs" / "reports.md"
KPIS_MARK = ("<!-- make docs-figures: kpis.json -->", "<!-- /make docs-figures -->")
#: the one line of a run's summary that is the machine's, not the code's
WALL = re.compile(r"simulated in [0-9.]+ s wall \([0-9.]+x real time\)")
CHROMIUM = ("chromium", "chromium-browser", "google-chrome")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars")


def railhil(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=900)


def lockstep_output(out: Path) -> list[str]:
    """The lines `railhil run scenarios/default.toml --lockstep --out OUT` prints, OUT written /tmp/tour."""
    proc = railhil("run", "scenarios/default.toml", "--lockstep", "--out", str(out), "-q")
    if proc.returncode != 0:
        raise SystemExit(f"docs-figures: the lockstep run failed (exit {proc.returncode}): {proc.stderr}")
    return [line.replace(str(out), TOUR) for line in proc.stdout.splitlines()]


def same_but_the_wall(a: list[str], b: list[str]) -> bool:
    """Whether two runs' outputs are the same but for the wall time of the first line."""
    return [WALL.sub("", x) for x in a] == [WALL.sub("", x) for x in b]


def console_blocks(text: str, command: str) -> list[tuple[int, int]]:
    """(start, end) of the output lines of each console block of `text` that runs `command`."""
    out = []
    for m in re.finditer(r"```console\n\$ " + re.escape(command) + r"\n(.*?)```", text, re.S):
        out.append((m.start(1), m.end(1)))
    return out


def printed(text: str, command: str) -> list[list[str]]:
    """The output each console block of `text` shows for `command`."""
    return [text[a:b].splitlines() for a, b in console_blocks(text, command)]


def with_output(text: str, command: str, lines: list[str]) -> str:
    """`text` with the output of every console block of `command` replaced by `lines`."""
    for a, b in reversed(console_blocks(text, command)):
        text = text[:a] + "".join(line + "\n" for line in lines) + text[b:]
    return text


def kpis_text(kpis: dict, width: int = 110) -> str:
    """kpis.json as the docs show it: sorted, one key a line, a list on one line, a short mapping of numbers
    on one line (wrapped at `width`), any other mapping one key a line."""
    def inline(v) -> str:
        return json.dumps(v, ensure_ascii=False)

    def block(obj: dict, indent: int) -> list[str]:
        pad = " " * indent
        lines = []
        keys = sorted(obj)
        for k, v in ((k, obj[k]) for k in keys):
            comma = "," if k != keys[-1] else ""
            head = f"{pad}{json.dumps(k)}: "
            if isinstance(v, dict) and v and (len(v) <= 7 or not all(isinstance(x, int | float)
                                                                      for x in v.values())):
                lines += [head + "{", *block(v, indent + 2), pad + "}" + comma]
            elif isinstance(v, dict) and v:
                items = [f"{json.dumps(a)}: {inline(b)}" for a, b in v.items()]
                line, cont = head + "{", " " * (len(head) + 1)
                for i, item in enumerate(items):
                    piece = item + (", " if i < len(items) - 1 else "}" + comma)
                    if len(line) + len(piece.rstrip()) > width:
                        lines.append(line.rstrip())
                        line = cont
                    line += piece
                lines.append(line)
            else:
                lines.append(head + inline(v) + comma)
        return lines

    return "\n".join(["{", *block(kpis, 2), "}"])


def marked(text: str, mark: tuple[str, str]) -> tuple[int, int] | None:
    """(start, end) of what lies between the two marker lines of `mark` in `text`."""
    a, b = text.find(mark[0]), text.find(mark[1], text.find(mark[0]) + 1)
    if a < 0 or b < 0:
        return None
    return a + len(mark[0]) + 1, b


def replace_marked(text: str, mark: tuple[str, str], fence: str, body: str) -> str:
    span = marked(text, mark)
    if span is None:
        return text
    return text[:span[0]] + f"```{fence}\n{body.rstrip()}\n```\n" + text[span[1]:]


def chromium() -> str | None:
    return next((found for name in CHROMIUM if (found := shutil.which(name))), None)


def screenshot(page: Path, png: Path, width: int = 1280, height: int = 900) -> bool:
    """The first screen of `page` at width × height in headless Chromium, into `png`; False without one."""
    browser = chromium()
    if browser is None:
        return False
    subprocess.run([browser, *CHROMIUM_FLAGS, f"--window-size={width},{height}",
                    "--virtual-time-budget=20000", f"--screenshot={png}", page.as_uri()],
                   capture_output=True, timeout=180)
    return png.is_file()


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="railhil-docs-figures-") as tmp:
        tmp = Path(tmp)
        lockstep = tmp / "tour"
        lines = lockstep_output(lockstep)
        shutil.copyfile(lockstep / "plot.png", PLOT)
        print(f"wrote {PLOT.relative_to(ROOT)}")
        for doc in DOCS:
            text = doc.read_text()
            new = with_output(text, LOCKSTEP_COMMAND, lines)
            kpis = json.loads((lockstep / "kpis.json").read_text())
            if doc == KPIS_DOC:
                new = replace_marked(new, KPIS_MARK, "json", kpis_text(kpis))
            if new != text:
                doc.write_text(new)
                print(f"wrote {doc.relative_to(ROOT)}")
        folder = f"runs/default-realtime-{time.strftime('%Y%m%d-%H%M%S')}"    # as make run names it
        realtime = tmp / folder
        proc = railhil("run", "scenarios/default.toml", "--realtime", "--fallback-lockstep", "--out",
                       str(realtime), "-q")
        if proc.returncode not in (0, 1):            # 1: real time not held, a verdict the docs show
            raise SystemExit(f"docs-figures: the real-time run failed (exit {proc.returncode}): "
                             f"{proc.stderr}")
        said = [line for line in proc.stderr.splitlines() if line.startswith("realtime: ")]
        output = "\n".join([*said, proc.stdout]).replace(str(realtime), folder).replace(str(ROOT) + "/", "")
        guide = ROOT / "docs" / "getting-started.md"
        text = guide.read_text()
        new = replace_marked(text, REALTIME_MARK, "text", output)
        if new != text:
            guide.write_text(new)
            print(f"wrote {guide.relative_to(ROOT)}")
        if screenshot(realtime / "report.html", SCREENSHOT):
            print(f"wrote {SCREENSHOT.relative_to(ROOT)}")
        else:
            print(f"notice: no headless Chromium here ({', '.join(CHROMIUM)}): {SCREENSHOT.name} not redrawn",
                  file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
