"""Every study has the same shape: one folder of hil/studies/ with the same files, listed by the registry,
with the hooks the foundation calls, its scenario section in the model and its reproduction on the
command line."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from hil.scenario import scenario_model
from hil.scenario.registry import PARTS, by_name, studies

ROOT = Path(__file__).resolve().parents[1]
STUDIES_DIR = ROOT / "hil" / "studies"
#: part -> the hooks every study's part defines (the foundation calls them unconditionally)
REQUIRED = {"nodes": ("node_names", "build_node"), "frames": ("messages", "signals"),
            "kpis": ("kpis", "summary_lines"), "plots": ("run_plots",), "reproduce": ("add_arguments", "run")}


def test_the_registry_lists_every_study_folder_once():
    folders = sorted(p.name for p in STUDIES_DIR.iterdir() if (p / "__init__.py").exists())
    assert sorted(s.name for s in studies()) == folders
    assert len({s.section for s in studies()}) == len(studies())


@pytest.mark.parametrize("study", studies(), ids=lambda s: s.name)
def test_every_study_has_the_same_files(study):
    files = sorted(p.name for p in (STUDIES_DIR / study.name).glob("*.py"))
    assert files == sorted(["__init__.py", *(f"{part}.py" for part in PARTS)])


@pytest.mark.parametrize("study", studies(), ids=lambda s: s.name)
def test_every_study_defines_the_hooks_the_foundation_calls(study):
    for part, hooks in REQUIRED.items():
        module = study.part(part)
        missing = [h for h in hooks if not callable(getattr(module, h, None))]
        assert not missing, f"hil/studies/{study.name}/{part}.py lacks {missing}"
    assert study.part("scenario").__doc__ and study.part("reproduce").__doc__


@pytest.mark.parametrize("study", studies(), ids=lambda s: s.name)
def test_every_study_section_is_in_the_scenario_model_and_optional(study):
    field = scenario_model().model_fields[study.section]
    assert field.default is None
    assert not study.active(scenario_model()())                 # the foundation's train runs no study


def test_every_study_reproduces_on_the_command_line():
    from hil.cli.main import build_parser

    parser = build_parser(["reproduce"])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    reproduce = sub.choices["reproduce"]
    names = next(a for a in reproduce._actions if isinstance(a, argparse._SubParsersAction)).choices
    for study in studies():
        assert study.cli_name in names
    assert names["picasso"] is names["preview-slip"] and names["acd"] is names["anticollision"]


def test_by_name_takes_the_folder_or_the_command_line_name():
    assert by_name("wheel-slip") is by_name("wheel_slip")
    with pytest.raises(KeyError, match="the studies are"):
        by_name("nonesuch")
