"""Both torch encoders on a real CUDA GPU, held to what they give on the CPU (skipped where there is no GPU).

The companion runs on a Jetson Orin's GPU, but CI and the development hosts have none: these tests run only on a
machine with CUDA (the project's GPU check host), and prove that ``encoder.device: cuda`` and ``auto`` put the work
on the GPU, at the precision the docs promise, with the scores and the summary the CPU gives.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import open_clip
import pytest
import torch

from companion.config import EncoderConfig
from companion.evaluation.roc import auroc
from companion.vision.encoders.clip import ClipEncoder
from companion.vision.encoders.imagenet import ImageNetEncoder
from tests.conftest import run_merlion, shared_file

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device here")

FISH = "underwater image with fish"
NO_FISH = "underwater image without fish"


def _cosines(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))


@pytest.fixture(scope="module")
def survey_frames() -> list[np.ndarray]:
    video = cv2.VideoCapture(str(shared_file("survey/survey_480x270.mp4")))
    frames = []
    ok, frame = video.read()
    while ok:
        frames.append(frame)
        ok, frame = video.read()
    video.release()
    return frames[::6]


def test_packaged_encoder_on_cuda_scores_real_frames_as_the_cpu_does(survey_frames):
    cpu = ImageNetEncoder(EncoderConfig(name="imagenet", device="cpu"))
    gpu = ImageNetEncoder(EncoderConfig(name="imagenet", device="cuda"))
    assert next(gpu._net.parameters()).device.type == "cuda"
    texts = cpu.encode_texts([FISH, NO_FISH])
    on_cpu, on_gpu = cpu.encode_images(survey_frames), gpu.encode_images(survey_frames)
    assert on_gpu.dtype == np.float32 and on_gpu.shape == on_cpu.shape
    pooled = slice(0, 1280)
    assert _cosines(on_cpu[:, pooled], on_gpu[:, pooled]).min() > 0.999
    assert np.abs(cpu.semantic_scores(on_cpu, texts) - gpu.semantic_scores(on_gpu, texts)).max() < 0.01
    assert _cosines(cpu.sampler_features(on_cpu), gpu.sampler_features(on_gpu)).min() > 0.999


def test_cuda_runs_one_batch_shape_whatever_the_gate_passes(survey_frames):
    """Each new batch size made cuDNN choose kernels again (179 ms per frame in the gated pipeline on an H100)."""
    gpu = ImageNetEncoder(EncoderConfig(name="imagenet", device="cuda", batch=8))
    sizes: list[int] = []
    gpu._net._conv_stem.register_forward_hook(lambda module, args, out: sizes.append(args[0].shape[0]))
    short = [gpu.encode_images(survey_frames[:n]) for n in (1, 3, 8)]
    assert sizes == [8, 8, 8] and [len(s) for s in short] == [1, 3, 8]
    for emb in short[:2]:  # the padding copies never leak into the frames' own rows
        np.testing.assert_allclose(emb, short[2][:len(emb)], rtol=1e-3, atol=1e-3)


def test_clip_on_cuda_auto_picks_fp16_and_agrees_with_fp32_on_the_cpu(tmp_path, survey_frames):
    torch.manual_seed(0)
    net = open_clip.create_model("ViT-B-32", pretrained=None)
    ckpt = tmp_path / "vit_b32.pt"
    torch.save({k: v.half() for k, v in net.state_dict().items()}, ckpt)
    cpu = ClipEncoder(EncoderConfig(name="clip", model="ViT-B-32", weights=str(ckpt), device="cpu", precision="fp32"))
    gpu = ClipEncoder(EncoderConfig(name="clip", model="ViT-B-32", weights=str(ckpt), device="auto"))
    weight = next(gpu._model.parameters())
    assert weight.device.type == "cuda" and weight.dtype == torch.float16
    on_cpu, on_gpu = cpu.encode_images(survey_frames), gpu.encode_images(survey_frames)
    assert on_gpu.dtype == np.float32
    assert _cosines(on_cpu, on_gpu).min() > 0.995
    # random towers make near-identical text embeddings: other frames' embeddings stand in for queries
    queries = on_cpu[::-1][:2]
    assert np.abs(cpu.semantic_scores(on_cpu, queries) - gpu.semantic_scores(on_gpu, queries)).max() < 0.01


def test_summarize_on_cuda_keeps_the_frames_the_cpu_keeps(tmp_path):
    video = shared_file("survey/survey_480x270.mp4")
    kept = {}  # encoder.device: cuda is refused where torch sees no GPU, so the second run is on the GPU
    for device in ("cpu", "cuda"):
        config = tmp_path / f"{device}.yaml"
        config.write_text(f"encoder:\n  name: imagenet\n  device: {device}\n")
        out = tmp_path / device
        done = run_merlion("summarize", str(video), "--out", str(out), "--config", str(config), "-k", "6")
        assert done.returncode == 0, done.stderr
        summary = json.loads((out / "summary.json").read_text())
        kept[device] = [f["index"] for f in summary["frames"]]
    assert kept["cuda"] == kept["cpu"] and len(kept["cpu"]) == 6


def test_scene_head_on_cuda_scores_a_fish_habitat_as_the_cpu_does(tmp_path):
    """``merlion score --dive`` streams a habitat's frames as one dive: the first by the pooled fish head, each
    later one by the scene head against the frames before it. The GPU's features feed the same running mean."""
    images = shared_file("deepfish/images")
    habitat = tmp_path / "7117"
    habitat.mkdir()
    for path in sorted(images.glob("7117_*.jpg")):
        (habitat / path.name).write_bytes(path.read_bytes())
    scores = {}
    for device in ("cpu", "cuda"):
        config = tmp_path / f"{device}.yaml"
        config.write_text(f"encoder:\n  name: imagenet\n  device: {device}\n")
        done = run_merlion("score", str(habitat), "--dive", "--json", "--query", "fish", "--config", str(config))
        assert done.returncode == 0, done.stderr
        rows = [json.loads(line) for line in done.stdout.splitlines()]
        scores[device] = {row["file"]: row["score"] for row in rows}
    assert len(scores["cpu"]) == 60 and scores["cuda"].keys() == scores["cpu"].keys()
    files = sorted(scores["cpu"])
    cpu, gpu = (np.array([scores[d][f] for f in files]) for d in ("cpu", "cuda"))
    assert np.abs(cpu - gpu).max() < 0.02
    fish = np.array(["no_fish" not in f for f in files])
    assert abs(auroc(cpu, fish) - auroc(gpu, fish)) < 0.01 and auroc(gpu, fish) > 0.7
