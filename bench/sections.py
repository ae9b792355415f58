"""Replace one ``## `` section of BENCHMARKS.md, leaving the others as they are."""

from __future__ import annotations

from pathlib import Path


def replace_section(title: str, lines: list[str], path: Path = Path("BENCHMARKS.md")) -> None:
    """Put ``lines`` (starting with ``## title``) in place of the section of that title, or append them."""
    old = path.read_text().splitlines() if path.exists() else ["# Benchmarks", ""]
    head = f"## {title}"
    try:
        start = old.index(head)
    except ValueError:
        path.write_text("\n".join([*old, *([""] if old and old[-1] else []), *lines, ""]))
        return
    end = next((k for k in range(start + 1, len(old)) if old[k].startswith("## ")), len(old))
    gap = [""] if end < len(old) and lines and lines[-1] else []  # a blank line before the next section
    path.write_text("\n".join([*old[:start], *lines, *gap, *old[end:]]).rstrip("\n") + "\n")


def other_sections(own: tuple[str, ...], path: Path = Path("BENCHMARKS.md")) -> list[str]:
    """Return the lines of every section not titled in ``own``, in the file's order, as they stand (so a
    benchmark that rewrites its own sections keeps every other benchmark's)."""
    if not path.exists():
        return []
    old = path.read_text().splitlines()
    heads = [k for k, line in enumerate(old) if line.startswith("## ")] + [len(old)]
    out: list[str] = []
    for start, end in zip(heads[:-1], heads[1:], strict=True):
        if old[start][3:] not in own:
            out += old[start:end]
    return out
