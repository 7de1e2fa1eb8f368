"""MkDocs hook: the CLI reference page, generated from railhil's argparse parsers at build time.

`on_files` builds the full parser of `railhil` (every subcommand's module loaded:
``hil.cli.main.build_parser(load=list(COMMANDS))``), walks it recursively through every
``argparse._SubParsersAction`` and adds the page ``reference/cli.md`` to the site's files.  Each command
gets its usage, its description and one table per argument group with every option and positional and
its help.  Nothing is written into docs/ on disk, so the page cannot drift from the code: a new
subcommand or option appears at the next build.

Each command's section has the id ``railhil-<word>-<word>...`` (tests/test_docs.py looks for them).
"""

from __future__ import annotations

import argparse
import html
import re
import sys
from pathlib import Path

from mkdocs.structure.files import File

PAGE = "reference/cli.md"
WIDTH = 100          # usage lines are wrapped at this width whatever the terminal that builds the docs

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:          # a checkout that is not installed: import hil from it
    sys.path.insert(0, str(ROOT))


def full_parser() -> argparse.ArgumentParser:
    from hil.cli.main import COMMANDS, build_parser

    return build_parser(load=list(COMMANDS))


def _page_content() -> str:
    try:
        return render()
    except Exception as exc:  # the build must fail, naming why, not publish an empty reference
        from mkdocs.exceptions import PluginError

        raise PluginError(f"docs/hooks/cli_reference.py: cannot build railhil's parser to generate "
                          f"{PAGE}: {type(exc).__name__}: {exc}") from exc


def subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, list[str], argparse.ArgumentParser]]:
    """(name, aliases, parser) of each subcommand of `parser`, in the order they were added.  argparse
    maps a subcommand's name and its aliases to the same parser, the name first."""
    out: list[tuple[str, list[str], argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            seen: dict[int, int] = {}
            for name, sub in action.choices.items():
                if id(sub) in seen:
                    out[seen[id(sub)]][1].append(name)
                else:
                    seen[id(sub)] = len(out)
                    out.append((name, [], sub))
    return out


def help_lines(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Subcommand name -> its one-line help, as `--help` lists it (subcommands added with help=...)."""
    out: dict[str, str] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                if choice.help and choice.help is not argparse.SUPPRESS:
                    out[choice.dest] = " ".join(choice.help.split())
    return out


def walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("railhil",)):
    """(path, aliases, parser) of `parser` and every subcommand below it, depth first."""
    yield path, [], parser
    for name, aliases, sub in subcommands(parser):
        for sub_path, sub_aliases, p in walk(sub, path + (name,)):
            yield sub_path, (aliases if p is sub else sub_aliases), p


def documented_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The options and positionals a reader can give (help not suppressed; not the subcommand slot)."""
    return [a for a in parser._actions
            if a.help is not argparse.SUPPRESS and not isinstance(a, argparse._SubParsersAction)]


def positional_name(action: argparse.Action) -> str:
    """A positional's name as usage shows it: its metavar when that is one word, else its dest."""
    return action.metavar if isinstance(action.metavar, str) else action.dest


def anchor(path: tuple[str, ...]) -> str:
    return "-".join(re.sub(r"[^a-z0-9]+", "-", word.lower()).strip("-") for word in path)


def _formatter(parser: argparse.ArgumentParser) -> argparse.HelpFormatter:
    try:
        return parser.formatter_class(prog=parser.prog, width=WIDTH)
    except TypeError:
        return parser._get_formatter()


def _usage(parser: argparse.ArgumentParser) -> str:
    fmt = _formatter(parser)
    fmt.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)
    return fmt.format_help().strip()


def _text(text: str | None, prog: str) -> str:
    if not text:
        return ""
    if "%(prog)" in text:
        text = text % {"prog": prog}
    return " ".join(text.split())


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    fmt = _formatter(parser)
    try:
        text = fmt._expand_help(action)
    except (KeyError, TypeError, ValueError):
        text = action.help or ""
    return " ".join(text.split())


def _value(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    fmt = _formatter(parser)
    if action.option_strings:
        default = fmt._get_default_metavar_for_optional(action)
    else:
        default = fmt._get_default_metavar_for_positional(action)
    try:
        return fmt._format_args(action, default)
    except (TypeError, ValueError):
        return str(action.metavar or action.dest)


def _default(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    value = action.default
    if value is None or value is argparse.SUPPRESS or value == [] or value is False:
        return ""
    if isinstance(value, (list, tuple)):
        return ", ".join(str(v) for v in value)
    return str(value)


def _code(text: str, breaks: bool = False) -> str:
    text = html.escape(text)
    if breaks:                      # a long list of choices may wrap after its commas
        text = text.replace(",", ",<wbr>")
    return f"<code>{text}</code>"


def _table(parser: argparse.ArgumentParser, actions: list[argparse.Action]) -> list[str]:
    rows = ["<table>", "<thead><tr><th>option</th><th>value</th><th>default</th><th>help</th></tr></thead>",
            "<tbody>"]
    for action in actions:
        names = ", ".join(_code(s) for s in action.option_strings) or _code(positional_name(action))
        value, default = _value(parser, action), _default(action)
        rows.append("<tr>"
                    f"<td>{names}</td>"
                    f"<td>{_code(value, breaks=True) if value and action.option_strings else ''}</td>"
                    f"<td>{_code(default) if default else ''}</td>"
                    f"<td>{html.escape(_help(parser, action))}</td>"
                    "</tr>")
    rows += ["</tbody>", "</table>"]
    return rows


def command_section(path: tuple[str, ...], aliases: list[str], parser: argparse.ArgumentParser) -> list[str]:
    level = "#" * min(len(path) + 1, 6)
    lines = [f"{level} `{' '.join(path)}` {{#{anchor(path)}}}", ""]
    if aliases:
        old = ", ".join(f"`{' '.join(path[:-1] + (a,))}`" for a in aliases)
        lines += [f"Also accepted: {old}.", ""]
    description = _text(parser.description, parser.prog)
    if description:
        lines += [f"<p>{html.escape(description, quote=False)}</p>", ""]
    lines += ["```text", _usage(parser), "```", ""]
    for group in parser._action_groups:
        actions = [a for a in group._group_actions if a in documented_actions(parser)]
        if not actions:
            continue
        title = group.title or "arguments"
        lines += [f"<p><strong>{html.escape(title)}</strong></p>", "", *_table(parser, actions), ""]
    subs = subcommands(parser)
    if subs:
        lines += ["Subcommands:", ""]
        for name, _aliases, sub in subs:
            sub_path = path + (name,)
            summary = help_lines(parser).get(name) or _text(sub.description, sub.prog).split(". ")[0]
            summary = html.escape(summary.rstrip("."), quote=False)
            link = f"- [`{' '.join(sub_path)}`](#{anchor(sub_path)})"
            lines.append(link + (f": {summary}" if summary else ""))
        lines.append("")
    epilog = _text(parser.epilog, parser.prog)
    if epilog:
        lines += [f"<p>{html.escape(epilog, quote=False)}</p>", ""]
    return lines


def render(parser: argparse.ArgumentParser | None = None) -> str:
    parser = parser or full_parser()
    lines = [
        "# Command-line reference",
        "",
        "This page is generated from railhil's argparse parsers each time the docs are built "
        "(`docs/hooks/cli_reference.py`), so it lists every subcommand and option the code has. "
        "`railhil COMMAND --help` prints the same text in a terminal. `python -m hil` is the same "
        "command as `railhil`.",
        "",
    ]
    for path, aliases, p in walk(parser):
        lines += command_section(path, aliases, p)
    return "\n".join(lines) + "\n"


def on_files(files, config):
    files.append(File.generated(config, PAGE, content=_page_content()))
    return files
