"""Teardown shared by the live companion's tests: no `merlion run` outlives the test that started it."""

from __future__ import annotations

import pytest

from tests.companion.live_harness import reap_companions


@pytest.fixture(autouse=True)
def _reap_companions():
    yield
    reap_companions()
