"""How many threads the torch encoders take: one per core, or OMP_NUM_THREADS where it is set."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from companion.vision.encoders.torch_runtime import intra_op_threads

PROBE = ("import torch; from companion.vision.encoders.torch_runtime import configure_threads; "
         "configure_threads(); print(torch.get_num_threads(), torch.get_num_interop_threads())")


def _threads_in_a_fresh_process(omp: str | None) -> tuple[list[int], str]:
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    if omp is not None:
        env["OMP_NUM_THREADS"] = omp
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return [int(v) for v in done.stdout.split()], done.stderr


def test_omp_num_threads_caps_the_encoder_threads_in_a_real_process():
    assert _threads_in_a_fresh_process("1") == ([1, 1], "")


def test_without_omp_num_threads_the_encoder_takes_one_thread_per_core():
    cores = len(os.sched_getaffinity(0))
    assert _threads_in_a_fresh_process(None)[0] == [cores, 1]


@pytest.mark.parametrize("value", ["two", "0", "-3"])
def test_a_value_that_is_not_a_positive_whole_number_falls_back_to_the_cores_and_says_so(monkeypatch, caplog,
                                                                                         value):
    monkeypatch.setenv("OMP_NUM_THREADS", value)
    assert intra_op_threads() == len(os.sched_getaffinity(0))
    assert f"OMP_NUM_THREADS={value!r}" in caplog.text
