"""The CLIP encoder with real open_clip architectures built with random weights and saved to a checkpoint.

No CLIP weights can be had here, so every test builds the real architecture, saves it, and loads it back through
the same code a vehicle uses (--weights). Two models loaded from the same file must agree exactly, while a model
that silently ignored the file would be a different random draw: that is what proves the loading code.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import open_clip
import pytest
import torch
from open_clip.transform import PreprocessCfg, image_transform_v2

from companion.config import EncoderConfig
from companion.errors import MerlionError
from companion.vision.encoders.clip import ClipEncoder
from companion.vision.encoders.factory import make_encoder
from companion.vision.encoders.torch_runtime import cpu_has_native_bf16
from tests.conftest import free_tcp_port, run_merlion, shared_file

SMALL = "ViT-S-32-alt"


def _save_random(model: str, path) -> tuple[str, torch.nn.Module]:
    torch.manual_seed(0)
    net = open_clip.create_model(model, pretrained=None)
    # fp16 halves the file; the model keeps the same rounded numbers, so both sides agree exactly.
    state = {k: v.half() for k, v in net.state_dict().items()}
    torch.save(state, path)
    net.load_state_dict(state)
    return str(path), net.eval()


@pytest.fixture(scope="module")
def small_ckpt(tmp_path_factory) -> str:
    return _save_random(SMALL, tmp_path_factory.mktemp("clip") / "small.pt")[0]


@pytest.fixture(scope="module")
def small_fp32(small_ckpt) -> ClipEncoder:
    return ClipEncoder(EncoderConfig(name="clip", model=SMALL, weights=small_ckpt, precision="fp32", batch=3,
                                     device="cpu"))  # the references below run open_clip on the CPU


@pytest.fixture(scope="module")
def b32(tmp_path_factory) -> tuple[str, torch.nn.Module]:
    return _save_random("ViT-B-32", tmp_path_factory.mktemp("clip") / "vit_b32.pt")


def _spread_queries(encoder: ClipEncoder, images: list[np.ndarray]) -> np.ndarray:
    """Random towers give near-identical text embeddings; other images' embeddings make scores that vary."""
    return encoder.encode_images(images[::-1])


@pytest.mark.slow
def test_score_cli_loads_the_checkpoint_given_with_weights(small_ckpt, small_fp32, images, tmp_path):
    files = [shared_file("suim/images/f_r_1965_.jpg"), shared_file("suim/images/n_l_12_.jpg")]
    cpu = tmp_path / "cpu.yaml"  # compared with the CPU encoder to 1e-5: a GPU host's cuDNN may round otherwise
    cpu.write_text("encoder:\n  device: cpu\n")
    proc = run_merlion("score", *map(str, files), "--encoder", "clip", "--model", SMALL, "--weights", small_ckpt,
                       "--precision", "fp32", "--config", str(cpu), "--json")
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["file"] for r in rows] == list(map(str, files))

    enc = small_fp32
    texts = enc.encode_texts(["underwater image with fish", "underwater image without fish"])
    ims = [cv2.imread(str(f)) for f in files]
    expected = enc.semantic_scores(enc.encode_images(ims), texts)
    np.testing.assert_allclose([r["score"] for r in rows], expected, atol=1e-5)

    torch.manual_seed(1)  # a model that ignored the file would be another random draw: its embeddings differ
    other = open_clip.create_model(SMALL, pretrained=None).eval()
    with torch.inference_mode():
        x = torch.stack([enc.preprocess(ims[0])])
        theirs = torch.nn.functional.normalize(other.encode_image(x), dim=-1).numpy()
    assert float(theirs[0] @ enc.encode_images(ims[:1])[0]) < 0.99


def test_fast_preprocessing_matches_open_clip_own_transform(small_fp32, images):
    enc = small_fp32
    fast = enc.encode_images(images)
    with torch.inference_mode():
        ref = torch.stack([enc.preprocess.reference(img) for img in images])
        slow = torch.nn.functional.normalize(enc._model.encode_image(ref), dim=-1).numpy()
    assert np.min(np.sum(fast * slow, axis=1)) > 0.999
    queries = _spread_queries(enc, images)
    slow_scores = enc.semantic_scores(slow, queries)
    assert np.std(slow_scores) > 0.05, "queries too alike to test anything"
    np.testing.assert_allclose(enc.semantic_scores(fast, queries), slow_scores, atol=0.01)


@pytest.mark.slow
def test_vit_b32_through_the_cli_agrees_with_open_clip_itself(b32, images, tmp_path):
    b32_ckpt, model = b32
    for i, img in enumerate(images):
        cv2.imwrite(str(tmp_path / f"img{i}.png"), img)  # PNG: lossless, so the CLI sees the same pixels
    proc = run_merlion("score", str(tmp_path), "--encoder", "clip", "--weights", b32_ckpt, "--precision", "fp32",
                       "--json")
    assert proc.returncode == 0, proc.stderr
    cli_scores = [json.loads(line)["score"] for line in proc.stdout.splitlines()]
    assert len(cli_scores) == len(images)

    # The reference: open_clip's own model, transform (PIL) and tokenizer, with nothing of ours in between.
    pcfg = PreprocessCfg(**open_clip.get_model_preprocess_cfg(model))
    transform = image_transform_v2(pcfg, is_train=False)
    tokenizer = open_clip.get_tokenizer("ViT-B-32")
    with torch.inference_mode():
        from PIL import Image

        x = torch.stack([transform(Image.fromarray(img[:, :, ::-1].copy())) for img in images])
        v = torch.nn.functional.normalize(model.eval().encode_image(x), dim=-1).double()
        t = torch.nn.functional.normalize(model.encode_text(tokenizer(
            ["underwater image with fish", "underwater image without fish"])), dim=-1).double()
        want = (100 * v @ t.T).softmax(dim=-1)[:, 0].numpy()
    np.testing.assert_allclose(cli_scores, want, atol=0.01)


@pytest.mark.parametrize("precision", ["fp16-weights", "bf16", "fp16", "int8"])
def test_reduced_precision_keeps_scores_within_0_01(small_ckpt, small_fp32, images, precision):
    ref = small_fp32
    low = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=small_ckpt, precision=precision))
    assert low.describe()["precision"] == precision
    queries = _spread_queries(ref, images)
    want = ref.semantic_scores(ref.encode_images(images[:3]), queries)
    got = low.semantic_scores(low.encode_images(images[:3]), queries)
    assert np.std(want) > 0.05, "queries too alike to test anything"
    np.testing.assert_allclose(got, want, atol=0.01)
    texts = ["underwater image with fish", "underwater image without fish"]
    np.testing.assert_allclose(low.encode_texts(texts), ref.encode_texts(texts), atol=0.02)


def test_int8_embeddings_point_the_same_way_as_fp32(small_ckpt, small_fp32, images):
    """Scores within 0.01 could hide a larger error when random towers make scores alike: compare directions too."""
    low = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=small_ckpt, precision="int8"))
    cos = np.sum(low.encode_images(images) * small_fp32.encode_images(images), axis=1)
    assert cos.min() > 0.995
    quantized = [m for m in low._model.visual.modules() if "quantized" in type(m).__module__]
    assert quantized, "int8 asked for but no layer was quantized"


def test_checkpoint_wrappers_and_the_legacy_format_load(tmp_path, small_ckpt, small_fp32, images):
    """Trainer checkpoints ({"state_dict": ...}, "module." prefixes) and pre-zip torch files load like plain ones."""
    state = torch.load(small_ckpt, weights_only=True)  # the encoder itself no longer holds the text tower
    wrapped = tmp_path / "wrapped.pt"
    torch.save({"state_dict": {f"module.{k}": v for k, v in state.items()}, "epoch": 3}, wrapped)
    legacy = tmp_path / "legacy.pt"
    torch.save(state, legacy, _use_new_zipfile_serialization=False)
    want = small_fp32.encode_images(images[:2])
    for path in (wrapped, legacy):
        enc = ClipEncoder(EncoderConfig(name="clip", device="cpu", model=SMALL, weights=str(path), precision="fp32"))
        np.testing.assert_allclose(enc.encode_images(images[:2]), want, atol=1e-5)


def test_a_checkpoint_of_another_architecture_is_a_one_line_error(small_ckpt):
    with pytest.raises(MerlionError, match="do not load into ViT-B-32"):
        ClipEncoder(EncoderConfig(name="clip", model="ViT-B-32", weights=small_ckpt, precision="fp32"))


@pytest.mark.slow
@pytest.mark.parametrize(("precision", "bound"), [("fp32", 0.85), ("fp16-weights", 0.45), ("bf16", 0.45),
                                                  ("int8", 0.7)])
@pytest.mark.slow
def test_loading_holds_one_copy_of_the_weights(tmp_path, precision, bound):
    """open_clip's loader held checkpoint and model at once (~2x the file); the mmap'd load of the image tower
    alone (the text tower is never read at load) stays well under the file's size (image tower ~58% of it). In
    bf16 and fp16-weights the fp32 pages are given back as each tensor is cast: the peak is the 16-bit tower
    (measured 0.34 of the file with the first batch), where holding both was ~0.88; in int8, as each layer group is packed (0.59, was
    ~0.96). fp32 measured 0.64. Peaks are VmHWM: ru_maxrss starts at pytest's own RSS, inherited across exec,
    which hid every peak below it."""
    torch.manual_seed(0)
    ckpt = tmp_path / "b32_fp32.pt"
    torch.save(open_clip.create_model("ViT-B-32", pretrained=None).state_dict(), ckpt)
    size_mb = ckpt.stat().st_size / 2**20
    code = (
        "import torch, open_clip\n"
        "from companion.config import EncoderConfig\n"
        "from companion.vision.encoders.clip import ClipEncoder\n"
        "from companion.vision.encoders.peak_rss import peak_rss_mb\n"
        "before = peak_rss_mb()  # VmHWM: ru_maxrss would start at pytest's own RSS, inherited across exec\n"
        f"enc = ClipEncoder(EncoderConfig(name='clip', device='cpu', weights={str(ckpt)!r}, precision={precision!r}))\n"
        "enc.encode_images([__import__('numpy').zeros((240, 320, 3), 'uint8')])\n"
        "print(before, peak_rss_mb())\n"
    )
    repo = Path(__file__).resolve().parents[3]  # this checkout's companion package, whatever pytest's cwd
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=repo)
    assert proc.returncode == 0, proc.stderr
    before, after = map(float, proc.stdout.split()[-2:])
    assert after - before < bound * size_mb, (before, after, size_mb)


def test_batches_give_the_same_embeddings_as_single_frames(small_fp32, images):
    batched = small_fp32.encode_images(images)  # batch=3: a full batch and a partial one
    single = np.concatenate([small_fp32.encode_images([img]) for img in images])
    np.testing.assert_allclose(batched, single, atol=1e-4)
    assert small_fp32.encode_images([]).shape == (0, 256)


def test_semantic_score_is_softmax_of_100_cosine():
    enc = ClipEncoder.__new__(ClipEncoder)  # scoring needs no model: check the formula on hand-made vectors
    img = np.array([[1.0, 0.0], [0.6, 0.8]], dtype=np.float32)
    txt = np.array([[1.0, 0.0], [0.0, 1.0], [0.8, 0.6]], dtype=np.float32)
    logits = 100 * img.astype(np.float64) @ txt.T.astype(np.float64)
    want = 1.0 / np.exp(logits - logits[:, :1]).sum(axis=1)
    np.testing.assert_allclose(enc.semantic_scores(img, txt), want, rtol=1e-5)


def test_auto_takes_clip_when_weights_exist_and_says_so(small_ckpt, caplog):
    with caplog.at_level(logging.DEBUG):
        enc = make_encoder(EncoderConfig(name="auto", model=SMALL, weights=small_ckpt))
    assert enc.name == f"clip:{SMALL}"
    assert any("using CLIP" in r.getMessage() and r.levelno == logging.INFO for r in caplog.records)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING and r.name.endswith(".factory")]


def test_auto_falls_back_to_the_packaged_encoder_without_an_alarm(caplog):
    """The packaged encoder is the offline default (README): said at INFO, never as a WARNING; why CLIP was not
    taken (and how to get it) at DEBUG, for -vv."""
    with caplog.at_level(logging.DEBUG):
        enc = make_encoder(EncoderConfig(name="auto", weights=None, pretrained=None))
    assert enc.name == "imagenet:efficientnet-lite0"
    said = [r for r in caplog.records if r.name.endswith(".factory")]
    assert any("packaged imagenet" in r.getMessage() and "offline default" in r.getMessage()
               and r.levelno == logging.INFO for r in said)
    assert any("--weights" in r.getMessage() and r.levelno == logging.DEBUG for r in said)
    assert not [r for r in said if r.levelno >= logging.WARNING]


def test_auto_with_empty_caches_never_imports_open_clip_and_a_cached_file_is_looked_up(tmp_path, monkeypatch):
    """The packaged-encoder start every new user meets skips open_clip (2.3 s); anything in a cache takes the
    full look-up, which the cached-tag test below follows to the checkpoint."""
    from huggingface_hub import constants

    from companion.vision.encoders.weights import caches_hold_checkpoints

    image = tmp_path / "frame.png"
    cv2.imwrite(str(image), np.full((64, 64, 3), 90, np.uint8))
    env = {"HOME": str(tmp_path), "HF_HOME": str(tmp_path / "hf")}
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "companion", "score", str(image)],
                          capture_output=True, text=True, timeout=120, env={**os.environ, **env},
                          cwd=Path(__file__).resolve().parents[3])
    assert done.returncode == 0, done.stderr[-2000:]
    assert "using the packaged imagenet encoder" in done.stderr and "WARNING" not in done.stderr
    imported = [line.rsplit("|", 1)[-1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")]
    assert "efficientnet_lite_pytorch" in imported and "open_clip" not in imported and "torch" in imported

    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setenv("HOME", str(tmp_path))
    assert not caches_hold_checkpoints()
    (tmp_path / ".cache" / "clip").mkdir(parents=True)
    (tmp_path / ".cache" / "clip" / "ViT-B-32.pt").write_bytes(b"x")
    assert caches_hold_checkpoints()


def test_missing_weights_file_is_a_one_line_error(tmp_path):
    with pytest.raises(MerlionError, match=r"no such file; run `merlion models pull ViT-B-32"):
        make_encoder(EncoderConfig(name="clip", weights=str(tmp_path / "nope.pt")))
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(MerlionError, match="do not load into ViT-B-32"):
        make_encoder(EncoderConfig(name="clip", weights=str(junk)))


def test_an_uncached_tag_is_a_one_line_error_naming_the_fix(tmp_path, monkeypatch):
    from huggingface_hub import constants

    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "hub"))  # an empty cache, wherever we run
    monkeypatch.setenv("HOME", str(tmp_path))  # ~/.cache/clip, open_clip's cache for URL tags
    for model, tag in (("ViT-B-32", "laion2b_s34b_b79k"), ("RN50", "openai")):
        with pytest.raises(MerlionError) as err:
            make_encoder(EncoderConfig(name="clip", model=model, pretrained=tag))
        message = str(err.value)
        assert message.startswith(f"no CLIP weights for {model} ({tag}) in the local cache")
        assert f"merlion models pull {model} --pretrained {tag}" in message and "--weights PATH" in message
        assert "\n" not in message


@pytest.mark.slow
def test_offline_pull_fails_in_one_line(tmp_path):
    env = {"HOME": str(tmp_path), "HF_HOME": str(tmp_path / "hf"),
           "HF_ENDPOINT": f"http://127.0.0.1:{free_tcp_port()}"}  # nothing listens there: no network, anywhere
    proc = run_merlion("models", "pull", "--cache-dir", str(tmp_path / "dl"), env=env)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()], proc.stderr
    assert proc.stderr.startswith("merlion: error: cannot download ViT-B-32 (laion2b_s34b_b79k): no network")
    assert not (tmp_path / "dl").exists() or not any((tmp_path / "dl").iterdir())


def test_native_bf16_is_read_from_the_cpu_flags():
    """(What ``auto`` makes of it: test_half_weights.py.)"""
    assert cpu_has_native_bf16("flags\t: fpu sse avx2 amx_bf16 amx_tile\n")
    assert cpu_has_native_bf16("flags\t: fpu avx512f avx512_bf16\n")
    assert not cpu_has_native_bf16("flags\t: fpu sse avx2 fma\n")


@pytest.mark.slow
def test_a_cached_tag_is_found_offline_by_auto_and_models_list(b32, tmp_path, monkeypatch, capsys):
    """Lay the checkpoint out as the Hugging Face cache does after `merlion models pull`, then look for it."""
    import argparse

    from huggingface_hub import constants

    from companion.commands.models import run_list

    snapshot = tmp_path / "hub" / "models--laion--CLIP-ViT-B-32-laion2B-s34B-b79K" / "snapshots" / "abc123"
    snapshot.mkdir(parents=True)
    (snapshot.parents[1] / "refs").mkdir()
    (snapshot.parents[1] / "refs" / "main").write_text("abc123")
    (snapshot / "open_clip_pytorch_model.bin").write_bytes(open(b32[0], "rb").read())
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setenv("HOME", str(tmp_path))

    enc = make_encoder(EncoderConfig(name="auto", pretrained="laion2b_s34b_b79k"))
    assert enc.describe()["weights_source"] == "cache:laion2b_s34b_b79k"
    assert enc.describe()["weights"] == str(snapshot / "open_clip_pytorch_model.bin")
    assert run_list(argparse.Namespace(all=False)) == 0
    out = capsys.readouterr().out
    assert f"clip\tViT-B-32:laion2b_s34b_b79k\t{snapshot / 'open_clip_pytorch_model.bin'}" in out
