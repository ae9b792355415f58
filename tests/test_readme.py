"""The commands of the README and docs/, checked as written: every module it runs exists and runs as a script, every
gsa subcommand it names exists, every gsa command line in its shell blocks parses as written, every option a gsa
mention names is one its command takes, every file such a command reads is in the repository or written by another
README command (or a capitalised placeholder: REQUEST.json), the first one an operator runs, run as written, every make target it
names is in the Makefile, and no command runs a file by path (``python bench/x.py`` cannot import the package it
lives in)."""

from __future__ import annotations

import importlib.util
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import build_parser, command_name

ROOT = Path(__file__).resolve().parents[1]
# The README and the documentation it leads to (docs/), read as one text.
README = "\n".join(p.read_text() for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))])
# Commands in code spans and in fenced blocks.
SNIPPETS = re.findall(r"`([^`\n]+)`", README) + re.findall(r"```(?:sh|bash)?\n(.*?)```", README, re.S)
TEXT = "\n".join(SNIPPETS)


def _block_commands() -> list[str]:
    """Every gsa command line of the README's shell blocks, continuation lines joined, comments dropped."""
    out = []
    for block in re.findall(r"```(?:sh|bash)?\n(.*?)```", README, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.split(r"\s+#", line)[0].strip()
            if line and not line.startswith("#") and re.search(r"(^|\s|/)gsa\s", line):
                out.append(line)
    return out


def _argv(line: str) -> list[str]:
    """A command line's arguments after ``gsa`` (environment assignments before it dropped)."""
    words = shlex.split(line)
    while words and re.match(r"^[A-Z_]+=", words[0]):
        words.pop(0)
    assert words and words[0].endswith("gsa"), line
    return words[1:]


BLOCK_COMMANDS = _block_commands()
# The options that name a file or folder a command reads, and those it writes; positional inputs of these commands.
READS = ("--pass", "--scene", "--plan", "--model", "--data", "--frames", "--base", "--run", "--models", "--without")
WRITES = ("--out", "--export", "--plot", "--preview")
POSITIONAL_INPUTS = ("plan", "campaign", "estimate", "pass", "labelled", "compare", "stations")
# Run as written (seconds each): the one the README's first paragraphs lead an operator to (test_cli runs the
# others' commands in their own words).
RUN_AS_WRITTEN = ("gsa simulate --pass examples/paper-plan.json",)


def _placeholder(word: str) -> bool:
    return bool(re.fullmatch(r"[A-Z][A-Z0-9_]*(\.[a-z0-9]+)?/?", word))


def _written() -> set[str]:
    out = set()
    for line in BLOCK_COMMANDS:
        argv = _argv(line)
        out |= {argv[k + 1].rstrip("/") for k in range(len(argv) - 1) if argv[k] in WRITES}
    return out


@pytest.mark.parametrize("line", BLOCK_COMMANDS)
def test_every_gsa_command_in_a_shell_block_parses_as_written(line):
    argv = _argv(line)
    try:
        build_parser(command_name(argv)).parse_args(argv)
    except SystemExit:
        pytest.fail(f"the README's command does not parse: {line}")


def test_every_file_a_readme_command_reads_is_there_or_written_by_another():
    assert len(BLOCK_COMMANDS) >= 20
    written = _written()
    missing = []
    for line in BLOCK_COMMANDS:
        argv = _argv(line)
        inputs = [argv[k + 1] for k in range(len(argv) - 1) if argv[k] in READS]
        if argv[0] in POSITIONAL_INPUTS:
            skip = {argv[k + 1] for k in range(len(argv) - 1) if argv[k].startswith("--")}
            inputs += [w for w in argv[1:] if not w.startswith("-") and w not in skip and w not in ("add",)]
        for word in inputs:
            if _placeholder(word) or "://" in word:
                continue
            if not (ROOT / word).exists() and word.rstrip("/") not in written:
                missing.append(f"{word} in: {line}")
    assert not missing, missing


def test_every_option_a_gsa_mention_names_is_its_commands():
    """``gsa estimate --no-refine`` in the prose: ``--no-refine`` is an option of ``gsa estimate``."""
    spans = re.findall(r"`([^`\n]+)`", README)
    mentions = [
        m.group(1) for span in spans if (m := re.match(r"^(?:\.venv/bin/)?(?:[A-Z_]+=\S+ )*gsa ([a-z].*)$", span))
    ]
    checked = 0
    for mention in mentions:
        argv = mention.split()
        parser = build_parser(command_name(argv))
        sub = parser._subparsers._group_actions[0].choices[argv[0]]  # argparse keeps the subcommands here
        if sub._subparsers is not None and len(argv) > 1 and argv[1] in sub._subparsers._group_actions[0].choices:
            sub = sub._subparsers._group_actions[0].choices[argv[1]]
        known = {o for a in sub._actions for o in a.option_strings}
        for word in argv:
            option = word.split("=")[0].strip("[]|,.;:()")
            if option.startswith("--"):
                assert option in known, f"gsa {argv[0]} takes no {option}: {mention}"
                checked += 1
    assert checked >= 20


@pytest.mark.parametrize("start", RUN_AS_WRITTEN)
def test_the_first_commands_run_as_written(start, tmp_path):
    """The README's own line, run in a folder beside the repository's examples: exit 0, and its output there."""
    line = next(c for c in BLOCK_COMMANDS + SNIPPETS if re.search(r"(^|/)" + re.escape(start), c))
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    argv = _argv(line)
    out = subprocess.run(
        [sys.executable, "-m", "app.cli", *argv], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, (line, out.stderr[-2000:])
    for k in range(len(argv) - 1):
        if argv[k] in WRITES:
            assert (tmp_path / argv[k + 1]).exists(), (line, argv[k + 1])


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
