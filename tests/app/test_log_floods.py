"""What keeps a flood from filling the disk or going unnoticed: repeated warnings held back, a short open-file
limit named at start."""

from __future__ import annotations

import logging
import subprocess
import sys
import time

from app.core.observability import RepeatFilter


def _logger(window_s: float) -> tuple[logging.Logger, list[str]]:
    lines: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())

    handler = Keep()
    handler.addFilter(RepeatFilter(window_s))
    lg = logging.getLogger(f"flood-{window_s}-{time.monotonic_ns()}")
    lg.handlers[:] = [handler]
    lg.propagate = False
    lg.setLevel(logging.INFO)
    return lg, lines


def test_a_repeated_error_is_one_line_a_window_and_the_next_says_how_many_were_held():
    lg, lines = _logger(0.5)
    for k in range(10_000):
        lg.error("socket.accept() out of system resource: %s", k)
    assert lines == ["socket.accept() out of system resource: 0"]
    time.sleep(0.6)
    lg.error("socket.accept() out of system resource: %s", "again")
    assert lines[1] == "socket.accept() out of system resource: again [9999 more like it in the last 0.5 s not logged]"


def test_other_messages_and_info_lines_all_pass():
    lg, lines = _logger(60.0)
    for k in range(50):
        lg.info("request %s", k)  # the access log: every request its line
    lg.warning("one thing")
    lg.warning("another thing")
    lg.error("one thing")  # another level: its own line
    assert len(lines) == 53


def test_an_open_file_limit_too_short_for_the_connections_is_named():
    """A process whose hard limit is 600 cannot hold 2048 connections: the warning says so and what to set."""
    code = (
        "import resource\n"
        "resource.setrlimit(resource.RLIMIT_NOFILE, (500, 600))\n"
        "from app.core.server import descriptor_warning, raise_descriptor_limit\n"
        "soft = raise_descriptor_limit(2048)\n"
        "assert resource.getrlimit(resource.RLIMIT_NOFILE)[0] == soft == 600, soft\n"
        "print(descriptor_warning(soft, 2048))\n"
        "print(descriptor_warning(raise_descriptor_limit(300), 300))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert "open-file limit is 600" in out[0] and "needs 2304" in out[0] and "GSA_MAX_CONNECTIONS=344" in out[0]
    assert out[1] == "None"  # 300 connections fit in 600
