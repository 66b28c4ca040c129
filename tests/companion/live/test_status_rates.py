"""The status figure says what it counts: frames scored per second beside the frames the camera delivered per second
(a gated or busy encoder scores fewer than it sees; "1.7 fps" alone was read as the camera's rate)."""

from __future__ import annotations

import re
import time

import pytest

from companion.live.loops import LiveCounters
from tests.conftest import run_merlion


def test_counters_say_scored_of_seen() -> None:
    c = LiveCounters()
    now = time.monotonic()
    for i in range(11):  # 10 frames/s seen over one second, every other one scored
        c.recent_seen.append(now - 1.0 + i * 0.1)
        if i % 2 == 0:
            c.recent.append(now - 1.0 + i * 0.1)
    assert c.rates_text(now) == "scored 5.0/s of 10.0/s seen"


@pytest.mark.slow
def test_the_companion_status_line_says_scored_of_seen(tmp_path) -> None:
    done = run_merlion("run", "--mavlink", "none", "--source", "synthetic://dive?seconds=8&width=160&height=96",
                       "--store", str(tmp_path / "store"), "--duration", "8", timeout=180)
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stderr.splitlines() if "companion stopped: " in x)
    match = re.search(r"; scored (\d+\.\d)/s of (\d+\.\d)/s seen; ", line)
    assert match and " fps" not in line, line
    scored, seen = map(float, match.groups())
    assert seen > 0 and scored <= seen + 0.5, line
