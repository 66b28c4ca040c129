"""`merlion --help` imports every command module to build its parser, so those modules import nothing heavy at the
top (docs/code-layout.md): no numpy, cv2, torch, pymavlink or pydantic, which took it from 0.2 s to 0.7-1.2 s
(`merlion bench`-style figures are in the commit; here only what is imported is checked, never a time)."""

from __future__ import annotations

import subprocess
import sys
from typing import get_args

from companion.commands.overrides import PRECISIONS
from companion.config import Precision
from tests.conftest import REPO

HEAVY = ("numpy", "cv2", "torch", "pymavlink", "pydantic", "yaml", "companion.config", "companion.topside",
         "companion.vision", "vehicle.link")


LOADED = "import sys, runpy\nsys.argv = {argv!r}\ntry:\n    runpy.run_module('companion', run_name='__main__')\n" \
         "except SystemExit:\n    pass\nprint('\\n'.join(sorted(sys.modules)), file=sys.stderr)"


def loaded_by(*args: str) -> set[str]:
    """Every module loaded once ``merlion ARGS`` has run, as ``python -m companion`` runs it."""
    code = LOADED.format(argv=["merlion", *args])
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    return set(done.stderr.split())


def test_merlion_help_imports_nothing_heavy_but_a_command_still_gets_what_it_runs():
    modules = loaded_by("--help")
    assert "companion.commands.surface" in modules and "companion.commands.summarize" in modules  # all listed
    heavy = sorted(m for m in modules if m.split(".")[0] in HEAVY or m.startswith(HEAVY))
    assert heavy == [], heavy
    ran = loaded_by("summarize", "no-such.mp4", "--out", "x")  # a command that runs imports the configuration
    assert "companion.config" in ran and "pydantic" in ran


def test_the_precision_choices_are_the_configurations():
    assert PRECISIONS == get_args(Precision)
