"""A store written under another encoder resumes with features this encoder made: the frames it names, or whose
feature has another length, are encoded again from their stored images (real encoder, real store on disk), the
store keeps the new features, and the next start encodes nothing."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from companion.config import EncoderConfig, StoreConfig
from companion.live.resume_features import refresh_features
from companion.storage.store import Store
from companion.vision import distances as dist
from companion.vision.encoders.counted import CountedEncoder
from companion.vision.encoders.visual import VisualEncoder
from companion.vision.events import SummaryEvent, SummaryFrame
from companion.vision.pipeline import downscale_for
from tests.companion.live_harness import Companion, store_summary, wait_until, write_config


def _frame(index: int, feature: np.ndarray) -> SummaryFrame:
    rng = np.random.default_rng(index)
    image = rng.integers(0, 255, size=(96, 160, 3), dtype=np.uint8)
    return SummaryFrame(image_index=index, frame_index=index, time_s=float(index), capture_time=1000.0 + index,
                        score=0.9, image=image, feature=feature.astype(np.float32))


def _store(folder: Path, features: list[tuple[np.ndarray, str]]) -> None:
    store = Store(StoreConfig(dir=str(folder)))
    for i, (feature, encoder) in enumerate(features):
        tags = {"encoder": encoder} if encoder else {}
        store.apply(SummaryEvent("added", _frame(i, feature), list(range(i + 1))), tags=tags)


def _expected(encoder: VisualEncoder, store: Store, index: int) -> np.ndarray:
    image = store.frame(index).image  # as stored (a JPEG), which is all a restart has
    emb = encoder.encode_images([downscale_for(image, encoder.input_size)])
    return dist.prepare_features(encoder.sampler_features(emb))[0]


def test_features_of_another_encoder_are_made_again_and_kept(tmp_path: Path, caplog) -> None:
    encoder = CountedEncoder(VisualEncoder(EncoderConfig(name="visual")))
    rng = np.random.default_rng(0)
    clip = rng.random(512)
    same_length_other = rng.random(379)
    _store(tmp_path, [(clip, "clip:ViT-B-32"), (same_length_other, "clip:other"), (rng.random(379), ""),
                      (rng.random(7), ""), (rng.random(379), "")])
    store = Store(StoreConfig(dir=str(tmp_path)))
    visual_4 = _expected(encoder.inner, store, 4)
    store.replace_feature(4, visual_4.astype(np.float32), "visual")  # one frame this encoder made
    untagged_right_length = store.frame(2).feature.copy()

    with caplog.at_level(logging.WARNING, logger="companion.live"):
        state = refresh_features(store.resume_state(), encoder, lambda im: downscale_for(im, encoder.input_size),
                                 store)
    assert encoder.images == 3  # frames 0, 1 (named another encoder) and 3 (7 values): nothing to learn the length
    assert [f.feature.size for f in state.frames] == [379] * 5
    for i in (0, 1, 3):
        np.testing.assert_allclose(state.frames[i].feature, _expected(encoder.inner, store, i), rtol=1e-5)
    np.testing.assert_array_equal(state.frames[2].feature, untagged_right_length)  # cannot tell: trusted
    line = [r.getMessage() for r in caplog.records if r.name == "companion.live.resume_features"]
    assert len(line) == 1 and "resumed frame(s) 0, 1, 3:" in line[0] and "made by clip:ViT-B-32" in line[0]
    assert "7 values, not 379" in line[0]

    again = Store(StoreConfig(dir=str(tmp_path)))  # the next start: the new features were kept on disk
    state = again.resume_state()
    assert all(state.encoders[i] == "visual" for i in (0, 1, 3, 4))
    np.testing.assert_allclose(state.frames[0].feature, _expected(encoder.inner, again, 0), rtol=1e-5)
    before = encoder.images
    refresh_features(state, encoder, lambda im: downscale_for(im, encoder.input_size), again)
    assert encoder.images == before


def test_a_store_without_any_frame_of_this_encoder_learns_its_length_from_one_frame(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    _store(tmp_path, [(rng.random(379), ""), (rng.random(379), "")])
    store = Store(StoreConfig(dir=str(tmp_path)))
    encoder = CountedEncoder(VisualEncoder(EncoderConfig(name="visual")))
    state = refresh_features(store.resume_state(), encoder, lambda im: downscale_for(im, encoder.input_size), store)
    assert encoder.images == 1 and [f.feature.size for f in state.frames] == [379, 379]


def test_merlion_run_resumes_a_store_of_another_encoder_and_keeps_sampling(tmp_path: Path) -> None:
    """Before, every batch failed at the sampler ("feature has 1280 dimensions, the summary holds 379") and the
    run kept nothing new."""
    store = tmp_path / "store"
    source = "synthetic://dive?seconds=60&width=160&height=96"
    common = {"mavlink": {"connection": None}, "store": {"dir": str(store)}, "queries": {"tau_ss": 0},
              "sampler": {"k": 4}, "source": {"uri": source}}
    first = Companion("--config", str(write_config(tmp_path / "visual.yaml", **common)))
    first.wait_for("companion running")
    wait_until(lambda: len(store_summary(store).get("summary", [])) >= 3, 60, "frames stored by the visual run")
    assert first.terminate() == 0, first.output
    held = store_summary(store)["summary"]
    next_index = store_summary(store)["next_image_index"]

    cfg = write_config(tmp_path / "imagenet.yaml", encoder={"name": "imagenet"}, **common)
    second = Companion("--config", str(cfg), "--source", source.replace("seconds=60", "seconds=60&seed=7"))
    line = second.wait_for("stored features not")
    assert f"resumed frame(s) {', '.join(map(str, held))}: stored features not imagenet" in line, line
    assert "made by visual" in line
    second.wait_for("companion running")

    def added_after_resume() -> bool:
        lines = (store / "changes.jsonl").read_text().splitlines()
        return any(json.loads(x).get("kind") == "added" and json.loads(x)["image_index"] >= next_index
                   for x in lines)
    wait_until(added_after_resume, 90, "a frame sampled after the resume")
    assert second.terminate() == 0, second.output
    assert "dimensions" not in second.output
    for i in store_summary(store)["summary"]:
        assert np.load(store / "frames" / f"{i:06d}.npy").shape == (1280,)
        assert json.loads((store / "frames" / f"{i:06d}.json").read_text())["tags"]["encoder"].startswith("imagenet")


def test_summary_json_names_the_new_encoder_from_the_start_of_the_run(tmp_path: Path) -> None:
    """summary.json holds each summary frame's sidecar; before, a resume under another encoder rewrote the frames'
    own sidecars but left summary.json naming the old encoder (and listing the old sidecars) until the next frame
    was stored, and forever if the run stored none (or was killed first)."""
    rng = np.random.default_rng(2)
    _store(tmp_path, [(rng.random(512), "clip:ViT-B-32"), (rng.random(512), "clip:ViT-B-32")])
    store = Store(StoreConfig(dir=str(tmp_path)))
    encoder = CountedEncoder(VisualEncoder(EncoderConfig(name="visual")))
    refresh_features(store.resume_state(), encoder, lambda im: downscale_for(im, encoder.input_size), store)
    doc = json.loads((tmp_path / "summary.json").read_text())  # on disk now, before any new frame
    assert [f["tags"]["encoder"] for f in doc["frames"]] == ["visual", "visual"]
    for i in (0, 1):
        assert json.loads((tmp_path / "frames" / f"{i:06d}.json").read_text())["tags"]["encoder"] == "visual"
