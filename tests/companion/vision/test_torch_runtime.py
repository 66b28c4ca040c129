"""How many threads the encoders take: one per usable core, or as many as OMP_NUM_THREADS sets."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.vision.encoders.cpu_threads import intra_op_threads, usable_cores

REPO = Path(__file__).resolve().parents[3]
PROBE = ("import torch; from companion.vision.encoders.torch_runtime import configure_threads; "
         "configure_threads(); print(torch.get_num_threads(), torch.get_num_interop_threads())")


def _threads_in_a_fresh_process(omp: str | None) -> tuple[list[int], str]:
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    if omp is not None:
        env["OMP_NUM_THREADS"] = omp
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    return [int(v) for v in done.stdout.split()], done.stderr


def test_omp_num_threads_sets_the_encoder_threads_in_a_real_process():
    wanted = usable_cores() + 1  # differs from the default on any machine
    threads, stderr = _threads_in_a_fresh_process(str(wanted))
    assert threads == [wanted, 1]
    assert "OMP_NUM_THREADS" not in stderr


def test_without_omp_num_threads_the_encoder_takes_one_thread_per_core():
    assert _threads_in_a_fresh_process(None)[0] == [usable_cores(), 1]


@pytest.mark.parametrize("value", ["two", "0", "-3", "\u00b2"])
def test_a_value_that_is_not_a_positive_whole_number_falls_back_to_the_cores_and_says_so(monkeypatch, caplog,
                                                                                         value):
    caplog.set_level(logging.WARNING, logger="companion.vision.encoders.cpu_threads")
    monkeypatch.setenv("OMP_NUM_THREADS", value)
    assert intra_op_threads() == usable_cores()
    assert f"OMP_NUM_THREADS={value!r}" in caplog.text
