"""`merlion demo --out` where no folder can be made: one error naming the folder, before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.errors import MerlionError
from companion.live.demo import DemoOptions, run_demo


def test_an_out_folder_that_cannot_be_created_is_named(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(MerlionError) as caught:
        run_demo(DemoOptions(out=blocker / "demo", duration=1.0, quiet=True))
    message = str(caught.value)
    assert message.startswith(f"--out {blocker / 'demo'}: cannot create {blocker / 'demo'}/")
    assert "\n" not in message
