"""A launcher's children: their output comes through the launcher, above a live display."""

from __future__ import annotations

import io
import re
import sys

from rich.console import Console
from rich.live import Live

from shared.processes import Processes

TALK = "import sys; print('a line on stdout'); print('a log line', file=sys.stderr)"


def test_a_childs_lines_come_through_the_launcher_each_on_its_own_line_above_a_live_display():
    screen = io.StringIO()
    console = Console(file=screen, force_terminal=True, width=60)
    with Live("frame 120  kills 3", console=console, auto_refresh=False), Processes() as children:
        assert children.start("talker", [sys.executable, "-c", TALK]).wait(60) == 0
    lines = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", screen.getvalue()).replace("\r", "\n").split("\n")
    assert "a line on stdout" in lines and "a log line" in lines  # whole lines, not glued on the display
