"""The informative sampler against hand-computed cases and a brute-force re-implementation of REFERENCE.md."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.vision import distances as dist
from companion.vision.sampler import InformativeSampler


def at(deg: float) -> np.ndarray:
    """A unit vector in the positive quadrant at this angle: cosine distances are 1 - cos(angle difference)."""
    r = math.radians(deg)
    return np.array([math.cos(r), math.sin(r), 0.0])


def cosd(a: float, b: float) -> float:
    return 1.0 - math.cos(math.radians(a - b))


def ref_kl(p, q) -> float:
    return sum(pi * math.log(pi / qi) for pi, qi in zip(p, q, strict=True) if pi > 0)


def ref_js(p, q) -> float:
    m = [(a + b) / 2 for a, b in zip(p, q, strict=True)]
    return 0.5 * ref_kl(p, m) + 0.5 * ref_kl(q, m)


def test_features_are_absolute_then_l2_normalised():
    f = dist.prepare_features(np.array([[-3.0, 4.0, 0.0]]))
    assert np.allclose(f, [[0.6, 0.8, 0.0]])
    assert np.allclose(dist.prepare_features(f), f)


def test_js_matches_the_definition_with_zero_guard():
    p = dist.prepare_features(np.array([0.0, 2.0, 1.0, 0.5]))
    qs = dist.prepare_features(np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 2.0, 1.0, 0.5], [3.0, 0.1, 0.2, 0.0]]))
    got = dist.js_many(p, qs)
    want = [ref_js(p, q) for q in qs]
    assert np.allclose(got, want, atol=1e-12)
    assert got[1] == pytest.approx(0.0, abs=1e-12)


def test_kl_direction_and_floor():
    p = dist.prepare_features(np.array([1.0, 2.0, 3.0]))
    qs = dist.prepare_features(np.array([[2.0, 2.0, 1.0], [1.0, 1.0, 1.0]]))
    assert np.allclose(dist.kl_many(p, qs), [ref_kl(p, q) for q in qs])
    assert np.allclose(dist.kl_many_reverse(p, qs, dist.xlogx_sum(qs)), [ref_kl(q, p) for q in qs])
    assert np.isfinite(dist.kl_many(p, np.array([[1.0, 0.0, 0.0]]))).all()


def test_warmup_takes_the_first_k_distinct_frames_unconditionally():
    s = InformativeSampler(k=3, distance="cosine")
    angles = [0, 0, 20, 21, 22, 60, 80]  # 21 is 1 degree from 20 (a duplicate); 22 is 2 from 20 and 1 from 21
    decisions = [s.offer(i, at(a)) for i, a in enumerate(angles)]
    assert [d.added for d in decisions][:6] == [True, False, True, False, False, True]
    assert [d.duplicate for d in decisions][:5] == [False, True, False, True, True]
    assert all(d.warmup for d in decisions[:6])
    assert s.keys[:3] == [0, 2, 5]
    assert not decisions[6].warmup


def test_alpha_must_be_strictly_greater_than_gamma():
    s = InformativeSampler(k=2, distance="cosine")
    s.offer(0, np.array([1.0, 0, 0]))
    s.offer(1, np.array([0, 1.0, 0]))
    assert s.gamma == pytest.approx(1.0)
    d = s.offer(2, np.array([0, 0, 1.0]))  # alpha = 1 = gamma
    assert d.alpha == pytest.approx(1.0)
    assert not d.added and s.keys == [0, 1]
    d = s.offer(3, np.array([1.0, 1.0, 0]))  # alpha = 1 - 1/sqrt(2)
    assert d.alpha == pytest.approx(1 - 1 / math.sqrt(2))
    assert not d.added


def test_hand_computed_gamma_alpha_and_trim_order():
    s = InformativeSampler(k=3, distance="cosine")
    for key, deg in enumerate([0, 10, 20]):
        s.offer(key, at(deg))
    assert s.gamma == pytest.approx(cosd(0, 10))
    d = s.offer(3, at(90))
    assert d.alpha == pytest.approx(cosd(20, 90))
    assert d.gamma == pytest.approx(cosd(0, 10))
    assert d.added
    # seed 90; farthest from {90} is 0 (d=1); then 20 (min(d(20,90), d(20,0)) = 0.060 > 0.015 for 10)
    assert d.removed == [1]
    assert s.keys == [0, 2, 3]


def test_trim_ties_go_to_the_earliest_inserted():
    s = InformativeSampler(k=2, distance="cosine")
    s.offer(0, np.array([1.0, 0, 0]))
    s.offer(1, np.array([1.0, 1.0, 0]))
    d = s.offer(2, np.array([0, 0, 1.0]))  # equally far (1.0) from both members
    assert d.added and d.removed == [1]
    assert s.keys == [0, 2]


@pytest.mark.parametrize(
    ("rule", "want"),
    [
        ("mean", (2 * cosd(0, 10) + cosd(10, 30) + cosd(30, 60)) / 4),
        ("min", cosd(0, 10)),
        ("2min", 2 * cosd(0, 10)),
        ("median", (cosd(0, 10) + cosd(10, 30)) / 2),
    ],
)
def test_threshold_rules(rule, want):
    s = InformativeSampler(k=4, distance="cosine", threshold=rule)
    for key, deg in enumerate([0, 10, 30, 60]):
        s.offer(key, at(deg))
    assert s.gamma == pytest.approx(want)


def brute_force(stream, k, distance, threshold):
    """REFERENCE.md steps 4-7 recomputed from scratch for every frame, with the reference distances."""
    ref = {"js": ref_js, "kl": ref_kl, "cosine": lambda p, q: 1.0 - float(np.dot(p, q))}[distance]
    held: list[tuple[int, np.ndarray]] = []
    for key, raw in enumerate(stream):
        v = dist.prepare_features(raw)
        if len(held) < k:
            held.append((key, v))
            continue
        nn = [min(ref(a, b) for j, (_, b) in enumerate(held) if j != i) if len(held) > 1 else 0.0
              for i, (_, a) in enumerate(held)]
        gamma = {"mean": np.mean, "min": np.min, "2min": lambda x: 2 * np.min(x), "median": np.median}[threshold](nn)
        alpha = min(ref(v, s) for _, s in held)
        if not alpha > gamma:
            continue
        cand = held + [(key, v)]
        new = [len(cand) - 1]
        while len(new) < k:
            best, best_d = None, -1.0
            for i, (_, f) in enumerate(cand):
                if i in new:
                    continue
                dmin = min(ref(f, cand[j][1]) for j in new)
                if dmin > best_d + 1e-12:
                    best, best_d = i, dmin
            new.append(best)
        held = [cand[i] for i in sorted(new)]
    return [key for key, _ in held]


@pytest.mark.parametrize("distance", ["js", "kl", "cosine"])
@pytest.mark.parametrize("threshold", ["mean", "min", "2min", "median"])
def test_matches_brute_force_reference(distance, threshold):
    rng = np.random.default_rng(7)
    stream = rng.normal(size=(40, 12)) * rng.uniform(0.2, 3.0, size=(40, 1))
    s = InformativeSampler(k=4, distance=distance, threshold=threshold)
    for key, raw in enumerate(stream):
        s.offer(key, raw)
    assert s.keys == brute_force(stream, 4, distance, threshold)


@pytest.mark.parametrize("k", [1, 3, 6])
def test_properties_bounded_subset_deterministic(k):
    rng = np.random.default_rng(k)
    stream = rng.normal(size=(120, 32))
    runs = []
    for _ in range(2):
        s = InformativeSampler(k=k)
        seen = []
        for key, raw in enumerate(stream):
            seen.append(key)
            s.offer(key, raw)
            assert len(s) <= k
            assert set(s.keys) <= set(seen)
        assert np.allclose(s.distance_matrix, dist.pairwise(s.features, "js"))
        runs.append(s.keys)
    assert runs[0] == runs[1]
    assert len(runs[0]) == k


def test_restore_resumes_exactly():
    rng = np.random.default_rng(3)
    stream = rng.normal(size=(80, 16))
    whole = InformativeSampler(k=5)
    first = InformativeSampler(k=5)
    for key, raw in enumerate(stream[:40]):
        whole.offer(key, raw)
        first.offer(key, raw)
    resumed = InformativeSampler(k=5)
    assert resumed.restore(zip(first.keys, first.features, strict=True)) == []
    for key, raw in enumerate(stream[40:], start=40):
        a, b = whole.offer(key, raw), resumed.offer(key, raw)
        assert (a.added, a.removed) == (b.added, b.removed)
    assert whole.keys == resumed.keys


def test_changing_k_at_runtime():
    s = InformativeSampler(k=4, distance="cosine")
    for key, deg in enumerate([0, 10, 30, 90]):
        s.offer(key, at(deg))
    removed = s.set_k(2)
    assert removed == [1, 2]  # seeded with the newest (90), the farthest from it is 0
    assert s.keys == [0, 3]
    s.set_k(3)
    assert s.offer(4, at(89)).duplicate  # not full, but the same picture as 90 never enters
    d = s.offer(5, at(80))  # not full: enters as in warm-up, however close
    assert d.added and d.warmup and s.keys == [0, 3, 5]
    with pytest.raises(ValueError):
        s.set_k(0)


def test_changing_distance_recomputes_the_matrix():
    rng = np.random.default_rng(1)
    s = InformativeSampler(k=4)
    for key, raw in enumerate(rng.normal(size=(10, 8))):
        s.offer(key, raw)
    s.configure(distance="kl", threshold="median")
    assert np.allclose(s.distance_matrix, dist.pairwise(s.features, "kl"))
