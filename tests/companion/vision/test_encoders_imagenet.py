"""The packaged EfficientNet-Lite0 encoder on real underwater images, and how its queries weigh classes."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from companion.config import EncoderConfig
from companion.errors import MerlionError
from companion.evaluation.roc import auroc
from companion.vision.encoders.imagenet import CLASSES, CPU_FORWARD_FRAMES, FEATURES, SCENE, ImageNetEncoder
from companion.vision.encoders.query_words import class_name, resolve_query
from companion.vision.pixel_scene import PIXELS, small_frame
from tests.conftest import shared_file

FISH = "underwater image with fish"
NO_FISH = "underwater image without fish"

WIDTH = FEATURES + 9 * (CLASSES + FEATURES) - FEATURES + PIXELS + SCENE
"""A row: pooled, 9 views' classes, 8 regions' features, the small frame, the scene slot."""


@pytest.fixture(scope="module")
def encoder() -> ImageNetEncoder:
    return ImageNetEncoder(EncoderConfig(name="imagenet"))


@pytest.fixture(scope="module")
def suim() -> tuple[list[np.ndarray], np.ndarray]:
    labels = shared_file("suim/labels.csv")
    rows = list(csv.DictReader(labels.open()))
    images = [cv2.imread(str(labels.parent / "images" / r["image"])) for r in rows]
    return images, np.array([int(r["fish_present"]) for r in rows])


def test_fish_images_outscore_no_fish_images_on_suim(encoder, suim):
    images, fish = suim
    emb = encoder.encode_images(images)
    # pooled, V class distributions, V - 1 regions, the small frame, and the scene residual (NaN: not part of a
    # dive yet)
    assert emb.shape == (len(images), WIDTH) and emb.dtype == np.float32
    assert np.isnan(emb[:, -SCENE:]).all() and np.isfinite(emb[:, :-SCENE]).all()
    scene = encoder.scene_of(emb)  # the small frames are the frames, resized
    np.testing.assert_allclose(scene.pixels[0], small_frame(cv2.resize(images[0], (448, 256),
                                                                      interpolation=cv2.INTER_AREA)), atol=1e-6)
    scores = encoder.semantic_scores(emb, encoder.encode_texts([FISH, NO_FISH]))
    assert np.all((scores > 0) & (scores < 1))
    assert scores[fish == 1].mean() > scores[fish == 0].mean() + 0.1  # "fish": the learned head (learned_head.py)
    assert auroc(scores, fish) >= 0.75


@pytest.mark.slow
def test_survey_video_fish_frames_separate_from_no_fish(encoder):
    video = shared_file("survey/survey_480x270.mp4")
    labels = [int(r["fish_present"]) for r in csv.DictReader(
        shared_file("survey/survey_480x270_labels.csv").open())]
    cap = cv2.VideoCapture(str(video))
    frames, fish = [], []
    for i in range(len(labels)):
        ok, frame = cap.read()
        if not ok:
            break
        if i % 4 == 0:
            frames.append(frame)
            fish.append(labels[i])
    cap.release()
    scores = encoder.semantic_scores(encoder.encode_images(frames), encoder.encode_texts([FISH, NO_FISH]))
    assert auroc(scores, fish) > 0.9


def test_regions_find_a_small_fish_the_whole_frame_misses(encoder):
    """A 1/16-area corner of an aquarium frame, pasted into a no-fish ROV frame: the region views see it."""
    fish_frame = cv2.imread(str(shared_file("aquarium_fish/frames/000010.jpg")))
    cap = cv2.VideoCapture(str(shared_file("rov_clips/V4361_20211006T162656Z_h265_1sec.mp4")))
    ok, rov = cap.read()
    cap.release()
    assert ok
    rov = cv2.resize(rov, (960, 540), interpolation=cv2.INTER_AREA)
    texts = encoder.encode_texts([FISH, NO_FISH])
    whole_only = ImageNetEncoder(EncoderConfig(name="imagenet"), regions=False)
    base = encoder.semantic_scores(encoder.encode_images([rov]), texts)[0]
    h, w = fish_frame.shape[:2]
    patch = cv2.resize(fish_frame[h // 4: 3 * h // 4, w // 4: 3 * w // 4], (240, 135))
    pasted = rov.copy()
    pasted[20:155, 700:940] = patch
    with_regions = encoder.semantic_scores(encoder.encode_images([pasted]), texts)[0]
    without = whole_only.semantic_scores(whole_only.encode_images([pasted]), texts)[0]
    assert with_regions > base
    assert with_regions > without


def test_default_queries_map_and_negation_is_the_complement(encoder, suim):
    pos, neg = resolve_query(FISH), resolve_query(NO_FISH)
    assert [t.noun for t in pos.terms] == ["fish"] and not pos.negated
    assert [t.noun for t in neg.terms] == ["fish"] and neg.negated
    emb = encoder.encode_images(suim[0][:3])
    pair = encoder.semantic_scores(emb, encoder.encode_texts([FISH, NO_FISH]))
    alone = encoder.semantic_scores(emb, encoder.encode_texts([FISH]))
    np.testing.assert_allclose(pair, alone, atol=1e-6)  # fish vs "not fish": the share is the fish mass
    texts = encoder.encode_texts([FISH, "a diver", "a coral reef"])
    mass = encoder.concept_masses(emb, texts)  # (N, 3): each concept's probability mass in the chosen view
    assert np.all(mass.sum(axis=1) <= 1 + 1e-5)  # disjoint class sets: their masses cannot exceed 1
    mass = encoder.with_head_masses(emb, texts, mass)  # "fish" is answered by the learned fish head
    np.testing.assert_allclose(encoder.semantic_scores(emb, texts), mass[:, 0] / mass.sum(axis=1), rtol=1e-5)
    np.testing.assert_allclose(mass[:, 0], alone, atol=1e-6)


def test_query_texts_become_class_weights(encoder):
    """Each query row holds its classes' weights (WordNet, query_words) and a negation flag; wording changes it."""
    rows = encoder.encode_texts(["fish", "fish or shark or ray or eel", "no sharks", "underwater image with fish"])
    fish = {class_name(i) for i in np.flatnonzero(rows[0, :CLASSES])}
    assert {"tench", "great white shark", "stingray", "lionfish", "anemone fish", "puffer", "eel"} <= fish
    assert set(np.unique(rows[0, :CLASSES])) == {0.0, 1.0} and rows[0, CLASSES] == 0
    np.testing.assert_array_equal(rows[3], rows[0])  # "underwater image with" says nothing about the content
    weighted = rows[1, :CLASSES]
    assert (np.flatnonzero(weighted) == np.flatnonzero(rows[0, :CLASSES])).all()
    assert weighted[[2, 3, 4, 5, 6, 390]].tolist() == [1.0] * 6 and weighted[0] == 0.5  # named fish weigh more
    assert np.flatnonzero(rows[2, :CLASSES]).tolist() == [2, 3, 4] and rows[2, CLASSES] == 1


@pytest.mark.parametrize("query", ["blorptang", "an underwater image", ""])
def test_unresolvable_query_is_refused_naming_it(encoder, query):
    with pytest.raises(MerlionError, match="blorptang" if query == "blorptang" else "names nothing"):
        encoder.encode_texts([FISH, query])


def test_mixed_negation_is_refused():
    with pytest.raises(MerlionError, match="mixes wanted and negated"):
        resolve_query("fish without divers")


def test_sampler_features_are_the_pooled_1280(encoder, suim):
    emb = encoder.encode_images(suim[0][:2])
    feats = encoder.sampler_features(emb)
    assert feats.shape == (2, FEATURES)
    assert not np.allclose(feats[0], feats[1])
    assert encoder.encode_images([]).shape == (0, WIDTH)


def test_mixed_portrait_and_landscape_batches_keep_frame_order(suim):
    enc = ImageNetEncoder(EncoderConfig(name="imagenet", batch=2))
    land = suim[0][4]
    port = np.ascontiguousarray(land.transpose(1, 0, 2))
    frames = [land, port, land, port, land]
    together = enc.encode_images(frames)
    alone = np.concatenate([enc.encode_images([f]) for f in frames])
    np.testing.assert_allclose(together, alone, atol=1e-4)
    assert not np.allclose(together[0], together[1])


def test_the_cpu_takes_two_frames_per_forward_whatever_the_batch(suim):
    """Eight frames at once ran slower and peaked 0.22 GB higher than two at a time (CPU_FORWARD_FRAMES)."""
    enc = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu", batch=8))
    sizes: list[int] = []
    enc._net._conv_stem.register_forward_hook(lambda module, args, out: sizes.append(args[0].shape[0]))
    land = [img for img in suim[0] if img.shape[1] >= img.shape[0]][:5]
    together = enc.encode_images(land)
    assert sizes == [CPU_FORWARD_FRAMES] * 2 + [1]
    alone = np.concatenate([enc.encode_images([f]) for f in land])
    np.testing.assert_allclose(together, alone, atol=1e-4)


def test_a_reduced_precision_is_ignored_with_a_warning_and_scores_stay_fp32(encoder, caplog):
    """The heads were fitted on fp32 features: `--precision int8` on the packaged encoder says so, not silently."""
    images = [cv2.imread(str(shared_file("suim/images/n_l_12_.jpg")))]
    with caplog.at_level("WARNING", logger="companion.vision.encoders.imagenet"):
        low = ImageNetEncoder(EncoderConfig(name="imagenet", precision="int8"))  # the fixture's device
    assert "encoder.precision int8: the packaged imagenet encoder runs in fp32 only; ignored" in caplog.text
    np.testing.assert_allclose(low.encode_images(images), encoder.encode_images(images), atol=1e-5)
