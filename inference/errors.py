"""Domain errors of the attitude-estimation half: bad input raises one of these, each a ValueError."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable


class InferenceError(ValueError):
    """Base class; ``field`` names the offending parameter or file."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class RadarError(InferenceError):
    """Radar parameters that describe no usable image (zero bandwidth, zero samples...)."""


class ModelFileError(InferenceError):
    """A target model file that is missing, unreadable, empty or does not fit the frame."""


class DatasetError(InferenceError):
    """A data set request or directory that cannot be used."""


class Cancelled(Exception):
    """Work stopped because whoever asked for it no longer waits (a client that went away); not bad input."""


def module_main(
    module: str,
    name: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    run: Callable[[argparse.Namespace], int],
    argv: list[str] | None = None,
    description: str | None = None,
) -> int:
    """``python -m inference.MODULE``: parse, run, and turn bad input into one line ("NAME: error: ...") and exit 2."""
    p = argparse.ArgumentParser(prog=f"python -m inference.{module}", description=description)
    add_arguments(p)
    try:
        return run(p.parse_args(argv))
    except InferenceError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2
