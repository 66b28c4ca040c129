"""A second writer on a store in use: `merlion run` and `merlion demo` stop with one line naming the store and the
holder's pid (exit 2), touch nothing, and the store takes a new run as soon as the holder is killed."""

from __future__ import annotations

from pathlib import Path

from tests.companion.live_harness import Companion, store_summary, wait_until, write_config
from tests.conftest import run_merlion


def _one_error(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("merlion: error: "), stderr
    return lines[0]


def test_a_second_run_and_a_demo_on_a_store_in_use_are_refused(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    store = out / "store"
    cfg = write_config(tmp_path / "c.yaml", mavlink={"connection": None}, store={"dir": str(store)},
                       source={"uri": "synthetic://dive?seconds=60&width=160&height=96"}, queries={"tau_ss": 0})
    first = Companion("--config", str(cfg))
    first.wait_for("companion running")
    wait_until(lambda: store_summary(store).get("summary"), 60, "a frame stored")
    dive = store_summary(store)["dive"]

    second = run_merlion("run", "--config", str(cfg), "--duration", "5", timeout=60)
    assert second.returncode == 2
    assert f"store {store}: in use by pid {first.proc.pid} " in _one_error(second.stderr)
    demo = run_merlion("demo", "--out", str(out), "--duration", "5", timeout=60)
    assert demo.returncode == 2
    assert f"store {store}: in use by pid {first.proc.pid} " in _one_error(demo.stderr)
    assert sorted(p.name for p in out.iterdir()) == ["store"], "the demo moved or wrote nothing"
    assert not list(tmp_path.glob("demo.previous-*"))
    assert first.alive() and store_summary(store)["dive"] == dive

    first.kill()  # SIGKILL: the kernel drops the lock with the process
    again = Companion("--config", str(cfg))
    again.wait_for("resuming with")
    assert again.terminate() == 0, again.output
