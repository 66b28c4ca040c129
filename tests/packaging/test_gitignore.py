"""What `merlion demo` leaves in the repository when run from its root (the default ./merlion-demo, and the earlier
run it moves aside) is ignored by git, so `git status` stays clean for a newcomer who tried it."""

from __future__ import annotations

import subprocess

from companion.live.demo import set_aside_previous_run
from tests.conftest import REPO


def ignored(path: str) -> bool:
    done = subprocess.run(["git", "-C", str(REPO), "check-ignore", "--no-index", "-q", path], timeout=30)
    assert done.returncode in (0, 1)
    return done.returncode == 0


def test_the_demo_folder_and_the_runs_it_moves_aside_are_ignored(tmp_path):
    out = tmp_path / "merlion-demo"
    (out / "store").mkdir(parents=True)
    (out / "report.json").write_text("{}")
    moved = set_aside_previous_run(out)  # the name the demo really gives it
    assert moved is not None and moved.name.startswith("merlion-demo.previous-")
    for name in ("merlion-demo", moved.name, f"{moved.name}-2"):
        assert ignored(f"{name}/report.json"), name
        assert ignored(f"{name}/store/summary.json"), name
    assert not ignored("companion/live/demo.py")
    assert not ignored("docs/merlion-demo.previous-notes.md")  # only folders at the root
