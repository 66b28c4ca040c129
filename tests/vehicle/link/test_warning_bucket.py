"""The bucket that bounds warnings about strangers: a burst, then one per refill period, from any thread."""

from __future__ import annotations

import threading
import time

from vehicle.link.warning_bucket import WarningBucket


def test_a_burst_passes_then_one_per_refill_period_from_many_threads():
    bucket = WarningBucket(burst=5, refill_s=60.0)
    taken: list[bool] = []
    threads = [threading.Thread(target=lambda: taken.extend(bucket.take() for _ in range(50))) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sum(taken) == 5  # 400 made-up senders, 5 warnings
    quick = WarningBucket(burst=1, refill_s=0.3)
    assert quick.take() and not quick.take()
    time.sleep(0.35)
    assert quick.take() and not quick.take()  # one more after a refill period, not a new burst
