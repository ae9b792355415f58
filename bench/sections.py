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


def kept_sections(titles: tuple[str, ...], path: Path = Path("BENCHMARKS.md")) -> list[str]:
    """Return the lines of the named sections as they stand (so a full rewrite can keep them)."""
    if not path.exists():
        return []
    old = path.read_text().splitlines()
    out: list[str] = []
    for title in titles:
        if f"## {title}" in old:
            start = old.index(f"## {title}")
            end = next((k for k in range(start + 1, len(old)) if old[k].startswith("## ")), len(old))
            out += old[start:end]
    return out
