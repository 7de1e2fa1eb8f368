"""The docs site: `mkdocs build --strict` passes, the generated CLI reference names every subcommand and
option of the full parser, and README.md stays short.

The build runs once for the module (a few seconds). It needs mkdocs and the Material theme (the `docs`
extra that `make test` installs); without them the build tests skip, saying so.
"""

from __future__ import annotations

import argparse
import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 300


def subcommands(parser: argparse.ArgumentParser):
    """(name, aliases, parser) of each subcommand of `parser`: argparse maps a name and its aliases to
    the same parser, the name first."""
    out: list[tuple[str, list[str], argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            index: dict[int, int] = {}
            for name, sub in action.choices.items():
                if id(sub) in index:
                    out[index[id(sub)]][1].append(name)
                else:
                    index[id(sub)] = len(out)
                    out.append((name, [], sub))
    return out


def commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("railhil",)):
    """(path, aliases, parser) of `parser` and every subcommand below it, each once under its name."""
    yield path, [], parser
    for name, aliases, sub in subcommands(parser):
        for sub_path, sub_aliases, p in commands(sub, path + (name,)):
            yield sub_path, (aliases if p is sub else sub_aliases), p


def section_id(path: tuple[str, ...]) -> str:
    return "-".join(re.sub(r"[^a-z0-9]+", "-", w.lower()).strip("-") for w in path)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    pytest.importorskip("mkdocs", reason="mkdocs is not installed (pip install -e '.[docs]'): the docs "
                                         "site cannot be built here")
    pytest.importorskip("material", reason="the mkdocs-material theme is not installed (pip install -e "
                                           "'.[docs]'): the docs site cannot be built here")
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}     # Material's end-of-life banner, not a warning
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, f"mkdocs build --strict failed (exit {proc.returncode}):\n{proc.stderr}"
    return out


def test_strict_build_passes(site):
    assert (site / "index.html").is_file()
    assert not (ROOT / "docs" / "reference" / "cli.md").exists(), \
        "docs/reference/cli.md must not exist on disk: the hook generates it at build time"


def test_cli_reference_names_every_command_and_option(site):
    from hil.cli.main import COMMANDS, build_parser

    page = (site / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    text = html.unescape(page)
    parser = build_parser(load=list(COMMANDS))

    ids = [m.start() for m in re.finditer(r'id="railhil[a-z0-9-]*"', page)]
    for path, aliases, p in commands(parser):
        name = " ".join(path)
        assert name in text, f"the CLI reference does not name `{name}`"
        for alias in aliases:                         # old names kept for a release
            old = " ".join(path[:-1] + (alias,))
            assert old in text, f"the CLI reference does not name `{old}` (an alias of `{name}`)"
        anchor = f'id="{section_id(path)}"'           # each command's options, in its own section
        start = page.find(anchor)
        assert start >= 0, f"the CLI reference has no section for `{name}` ({anchor})"
        end = min((i for i in ids if i > start), default=len(page))
        section = html.unescape(page[start:end])
        for action in p._actions:
            if action.help is argparse.SUPPRESS or isinstance(action, argparse._SubParsersAction):
                continue
            positional = action.metavar if isinstance(action.metavar, str) else action.dest
            for option in action.option_strings or [positional]:
                assert f">{option}<" in section, \
                    f"the CLI reference's section of `{name}` does not list {option}"


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, \
        f"README.md has {len(lines)} lines, at most {README_MAX_LINES}: move the detail into docs/"
