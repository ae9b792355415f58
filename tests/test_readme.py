"""The README's commands, checked as written: every module it runs exists and runs as a script, every
gsa subcommand it names exists, every make target it names is in the Makefile, and no command runs a
file by path (``python bench/x.py`` cannot import the package it lives in)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

from app.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
# Commands in code spans and in fenced blocks.
SNIPPETS = re.findall(r"`([^`\n]+)`", README) + re.findall(r"```(?:sh|bash)?\n(.*?)```", README, re.S)
TEXT = "\n".join(SNIPPETS)


def test_no_command_runs_a_python_file_by_path():
    assert not re.findall(r"python3? (?!-)[\w/]+\.py", TEXT)


@pytest.mark.parametrize("module", sorted(set(re.findall(r"python3? -m ([\w.]+)", TEXT))))
def test_every_python_m_module_exists_and_runs_as_a_script(module):
    if module in ("pytest", "venv", "pip"):
        return
    spec = importlib.util.find_spec(module)
    assert spec is not None and spec.origin, module
    assert '__name__ == "__main__"' in Path(spec.origin).read_text(), f"{module} has no script entry point"


def test_every_gsa_subcommand_named_exists():
    parser = build_parser()
    choices = parser._subparsers._group_actions[0].choices  # argparse keeps the subcommands here
    named = set(re.findall(r"(?:^|[\s/(])gsa ([a-z][a-z-]+)", TEXT, re.M))
    assert named, "the README names no gsa command?"
    assert named <= set(choices), named - set(choices)


def test_every_make_target_named_exists():
    makefile = (ROOT / "Makefile").read_text()
    targets = set(re.findall(r"^([a-z][\w-]*):", makefile, re.M))
    named = set(re.findall(r"\bmake ([a-z][\w-]*)", TEXT))
    assert named and named <= targets, named - targets


def test_every_cited_measurement_has_its_section():
    """Docstrings cite design/measurements.md by heading instead of carrying figures; each heading exists."""
    headings = set(re.findall(r"^## (.+)$", (ROOT / "design" / "measurements.md").read_text(), re.M))
    cited = set()
    for folder in ("app", "planner", "inference"):
        for path in (ROOT / folder).rglob("*.py"):
            for name in re.findall(r'design/measurements\.md,\s+"([^"]+)"', path.read_text()):
                cited.add(" ".join(name.split()))
    assert len(cited) >= 8
    assert cited <= headings, cited - headings
