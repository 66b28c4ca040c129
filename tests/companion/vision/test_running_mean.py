"""The dive's causal running mean: what a frame is centred on."""

import numpy as np
import pytest

from companion.vision.running_mean import RunningMean


def test_take_compares_with_the_frames_before_and_centre_with_this_frame_included():
    values = [2.0, 4.0, 9.0]
    before, included = RunningMean(0.0, 0.0, tau=100), RunningMean(0.0, 0.0, tau=100)
    took = [before.take(v) for v in values]
    centred = [included.centre(v) for v in values]
    assert took == pytest.approx([2.0, 4.0 - 2.0, 9.0 - 3.0])  # the first against the prior (weight 0)
    assert centred == pytest.approx([0.0, 4.0 - 3.0, 9.0 - 5.0])
    assert before.mean == included.mean == pytest.approx(5.0) and before.weight == included.weight == 3.0


def test_take_on_vectors_past_tau_forgets_exponentially():
    mean = RunningMean(np.zeros(2), 0.0, tau=2)
    for v in ([1.0, 0.0], [3.0, 0.0]):
        mean.take(np.array(v))
    np.testing.assert_allclose(mean.mean, [2.0, 0.0])
    out = mean.take(np.array([6.0, 2.0]))  # rate 1/2 from the third frame on (1/3 < 1/tau)
    np.testing.assert_allclose(out, [4.0, 2.0])
    np.testing.assert_allclose(mean.mean, [4.0, 1.0])
