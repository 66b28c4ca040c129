"""CLIP with ``runtime: onnx`` (issue 14 item 4): the running process never imports torch.

Real open_clip architectures with random weights saved to a checkpoint; the first start's export and every query
not in the cache run in a real child process (``clip_child``); the torch-free start runs in a fresh interpreter,
where ``sys.modules`` tells whether torch was imported.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import open_clip
import pytest
import torch

from companion.config import EncoderConfig
from companion.errors import MerlionError
from companion.vision.encoders.clip import ClipEncoder, ClipPreprocess
from companion.vision.encoders.clip_pixels import NumpyClipPreprocess
from companion.vision.encoders.cpu_threads import usable_cores
from companion.vision.encoders.factory import make_encoder
from companion.vision.encoders.onnx_clip import OnnxClipEncoder
from tests.conftest import run_merlion, shared_file

SMALL = "ViT-S-32-alt"
QUERIES = ["underwater image with fish", "underwater image without fish"]
REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> str:
    torch.manual_seed(3)
    path = tmp_path_factory.mktemp("onnx_clip") / "small.pt"
    torch.save(open_clip.create_model(SMALL, pretrained=None).state_dict(), path)
    return str(path)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("onnx_cache"))


def _cfg(ckpt: str, cache_dir: str, **kw) -> EncoderConfig:
    return EncoderConfig(name="clip", model=SMALL, weights=ckpt, precision="fp32", runtime="onnx", batch=3,
                         cache_dir=cache_dir, **kw)


@pytest.fixture(scope="module")
def onnx_enc(ckpt, cache_dir) -> OnnxClipEncoder:
    """The first start: the tower is exported by a child process into the cache."""
    return make_encoder(_cfg(ckpt, cache_dir))


@pytest.fixture(scope="module")
def torch_enc(ckpt) -> ClipEncoder:
    # the CPU fp32 tower the ONNX export is made from, and the references below run on the CPU
    return ClipEncoder(EncoderConfig(name="clip", model=SMALL, weights=ckpt, precision="fp32", batch=3, device="cpu"))


def open_clip_texts(ckpt: str, texts: list[str]) -> np.ndarray:
    """open_clip's own loader, tokenizer and text tower, in this process: nothing of ours in between."""
    net = open_clip.create_model(SMALL, pretrained=ckpt).eval()
    with torch.inference_mode():
        emb = net.encode_text(open_clip.get_tokenizer(SMALL)(texts))
    return torch.nn.functional.normalize(emb, dim=-1).numpy()


def test_numpy_preprocessing_equals_open_clip_s_transform(images):
    """The same input as open_clip's PIL pipeline (PIL resizes in both; measured: identical floats, bound 1e-6).
    The torch runtime's fast path (torch's antialiased resize) is the looser one: measured up to 9 uint8 steps on
    the upscaled frame, 3 elsewhere, 0.08-0.18 steps on average; bound 10 and 0.25."""
    model = open_clip.create_model(SMALL, pretrained=None, device="meta")
    pcfg = open_clip.get_model_preprocess_cfg(model)
    ours = NumpyClipPreprocess(pcfg)
    torch_fast = ClipPreprocess(pcfg)
    for img in images:
        want = torch_fast.reference(img).numpy()  # open_clip.image_transform on the PIL image
        got = ours(img)
        assert got.shape == want.shape == (3, 224, 224) and got.dtype == np.float32
        assert np.abs(got - want).max() < 1e-6
        assert ours.resized(img).shape == (224, 224, 3) and ours.resized(img).dtype == np.uint8
        one_step = 1.0 / 255 / min(ours.std.flatten())  # a uint8 step after normalisation
        diff = np.abs(torch_fast(img).numpy() - got)
        assert diff.max() < 10 * one_step and diff.mean() < 0.25 * one_step


@pytest.mark.slow
def test_onnx_embeddings_equal_torch_fp32_and_the_first_start_exported_in_a_child(onnx_enc, torch_enc, images):
    assert not onnx_enc.cached and onnx_enc.child_peaks_mb["export"] > 0
    got, want = onnx_enc.encode_images(images), torch_enc.encode_images(images)
    assert np.sum(got * want, axis=1).min() > 0.9999  # torch's resize differs from PIL's by a few uint8 steps
    texts = onnx_enc.encode_texts(QUERIES)
    np.testing.assert_allclose(texts, open_clip_texts(onnx_enc._cfg.weights, QUERIES), atol=1e-5)
    spread = torch_enc.encode_images(images[::-1])  # random towers' texts are alike: images make varied scores
    np.testing.assert_allclose(onnx_enc.semantic_scores(got, spread), torch_enc.semantic_scores(want, spread),
                               atol=0.01)
    with torch.inference_mode():  # against the reference transform itself: the only difference is the runtime
        ref = torch.stack([torch_enc.preprocess.reference(img) for img in images])
        exact = torch.nn.functional.normalize(torch_enc._model.encode_image(ref), dim=-1).numpy()
    np.testing.assert_allclose(got, exact, atol=1e-4)
    assert onnx_enc.encode_images([]).shape == (0, 256)
    assert onnx_enc.describe()["runtime"] == "onnx" and onnx_enc.describe()["export_cached"] is False


_FRESH = """
import json, sys
import numpy as np
import cv2
from companion.config import EncoderConfig
from companion.vision.encoders.factory import make_encoder
cfg = EncoderConfig(**json.loads(sys.argv[1]))
enc = make_encoder(cfg)
loaded = "torch" in sys.modules or "open_clip" in sys.modules
frames = [cv2.imread(p) for p in json.loads(sys.argv[2])]
np.save(sys.argv[3] + "/images.npy", enc.encode_images(frames))
np.save(sys.argv[3] + "/queries.npy", enc.encode_texts(json.loads(sys.argv[4])))
np.save(sys.argv[3] + "/changed.npy", enc.encode_texts(json.loads(sys.argv[5])))  # a live query change
print(json.dumps({"cached": enc.cached, "torch_after_load": loaded, "children": enc.child_peaks_mb,
                  "torch_at_end": "torch" in sys.modules or "open_clip" in sys.modules}))
"""


def test_a_start_from_the_cache_never_imports_torch_and_a_query_change_runs_in_a_child(
        onnx_enc, ckpt, cache_dir, torch_enc, images, tmp_path):
    onnx_enc.encode_texts(QUERIES)  # the first start cached these
    files = []
    for i, img in enumerate(images):
        files.append(str(tmp_path / f"img{i}.png"))  # PNG: the child reads the same pixels
        cv2.imwrite(files[-1], img)
    changed = ["a shipwreck on sand", QUERIES[1]]
    cfg = _cfg(ckpt, cache_dir).model_dump()
    proc = subprocess.run([sys.executable, "-c", _FRESH, json.dumps(cfg), json.dumps(files), str(tmp_path),
                           json.dumps(QUERIES), json.dumps(changed)],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["cached"] is True and out["torch_after_load"] is False and out["torch_at_end"] is False
    assert list(out["children"]) == ["texts"]  # only the new query needed torch, in its own process

    np.testing.assert_array_equal(np.load(tmp_path / "images.npy"), onnx_enc.encode_images(images))
    np.testing.assert_array_equal(np.load(tmp_path / "queries.npy"), onnx_enc.encode_texts(QUERIES))
    np.testing.assert_allclose(np.load(tmp_path / "changed.npy"), open_clip_texts(ckpt, changed), atol=1e-5)


def test_an_error_in_the_child_comes_back_as_one_line(tmp_path):
    torch.manual_seed(0)
    wrong = tmp_path / "small.pt"  # a checkpoint of another architecture than the configured one
    torch.save(open_clip.create_model(SMALL, pretrained=None).state_dict(), wrong)
    with pytest.raises(MerlionError) as err:
        make_encoder(EncoderConfig(name="clip", model="ViT-B-32", weights=str(wrong), runtime="onnx",
                                   precision="fp32", cache_dir=str(tmp_path / "cache")))
    message = str(err.value)
    assert message.startswith("CLIP ViT-B-32: could not export the image tower to ONNX: CLIP weights ")
    assert "do not load into ViT-B-32" in message and "\n" not in message
    assert not list((tmp_path / "cache").rglob("*.onnx")) and not list((tmp_path / "cache").rglob("*.json"))


def test_settings_the_onnx_runtime_cannot_honour_are_one_line_errors(ckpt, cache_dir):
    import onnxruntime as ort

    with pytest.raises(MerlionError, match="encoder.runtime onnx runs the fp32 export"):
        make_encoder(_cfg(ckpt, cache_dir).model_copy(update={"precision": "bf16"}))
    if "CUDAExecutionProvider" not in ort.get_available_providers():
        with pytest.raises(MerlionError, match="encoder.providers: CUDAExecutionProvider is not in"):
            make_encoder(_cfg(ckpt, cache_dir, providers=["CUDAExecutionProvider", "CPUExecutionProvider"]))
    with pytest.raises(MerlionError, match="only with encoder.runtime onnx"):
        make_encoder(EncoderConfig(name="clip", model=SMALL, weights=ckpt, providers=["CPUExecutionProvider"]))


def test_the_onnx_session_takes_as_many_threads_as_omp_num_threads_sets(onnx_enc, ckpt, cache_dir, monkeypatch):
    """ONNX Runtime does not read OMP_NUM_THREADS once the session names its threads: the encoder passes it on."""
    wanted = usable_cores() + 1
    monkeypatch.setenv("OMP_NUM_THREADS", str(wanted))
    again = make_encoder(_cfg(ckpt, cache_dir))  # from the cache: no export, no torch
    assert again.cached and again._session.get_session_options().intra_op_num_threads == wanted


@pytest.mark.slow
def test_replaced_weights_export_afresh(onnx_enc, ckpt, cache_dir, tmp_path):
    again = make_encoder(_cfg(ckpt, cache_dir))
    assert again.cached and again.child_peaks_mb == {}
    assert {p.suffix for p in (Path(cache_dir) / "onnx").iterdir()} == {".onnx", ".json"}  # no temporary left
    other = tmp_path / "other.pt"  # other weights (here: the same bytes, another file) are another key
    other.write_bytes(Path(ckpt).read_bytes())
    assert not make_encoder(_cfg(str(other), cache_dir)).cached


@pytest.mark.slow
def test_bench_pipeline_reports_the_main_process_peaks_and_the_children_s_apart(ckpt, tmp_path):
    """First start with the ONNX runtime: the export and query children's peaks are their own JSON field."""
    proc = run_merlion("bench", "pipeline", str(shared_file("survey/survey_480x270.mp4")), "--encoder", "clip",
                       "--model", SMALL, "--weights", ckpt, "--runtime", "onnx", "--precision", "fp32",
                       "--fps", "5", "--frames", "6", "--batch", "3", "--paper-frames", "0", "--json",
                       env={"HOME": str(tmp_path)})  # the default cache, ~/.cache/merlion, starts empty
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["encoder"]["runtime"] == "onnx" and result["encoder"]["export_cached"] is False
    assert result["peak_rss_mb"] >= result["load_peak_rss_mb"] > 0 and result["steady_rss_mb"] > 0
    assert set(result["child_peak_rss_mb"]) == {"export", "texts"}
    assert all(v > 0 for v in result["child_peak_rss_mb"].values())
    assert "export child" in proc.stdout
    assert list((tmp_path / ".cache" / "merlion" / "onnx").glob("*.onnx"))


_AUTO_TAG = """
import json, sys
from companion.config import EncoderConfig
from companion.vision.encoders.factory import make_encoder
enc = make_encoder(EncoderConfig(name=sys.argv[2], runtime="onnx", pretrained="laion2b_s34b_b79k",
                                 cache_dir=sys.argv[1]))
enc.encode_texts(["underwater image with fish", "underwater image without fish"])
print(json.dumps({**enc.describe(), "children": enc.child_peaks_mb, "torch": "torch" in sys.modules}))
"""


@pytest.mark.slow
def test_a_cached_tag_is_found_by_a_child_and_recorded_so_auto_starts_without_torch(tmp_path):
    """Looking a pretrained tag up needs open_clip: the first start (encoder clip) has its child find the file and
    export; the file is recorded, so the next start, with auto's check included, imports no torch either."""
    torch.manual_seed(0)
    snapshot = tmp_path / "hub" / "models--laion--CLIP-ViT-B-32-laion2B-s34B-b79K" / "snapshots" / "abc123"
    snapshot.mkdir(parents=True)
    (snapshot.parents[1] / "refs").mkdir()
    (snapshot.parents[1] / "refs" / "main").write_text("abc123")
    weights = snapshot / "open_clip_pytorch_model.bin"
    torch.save({k: v.half() for k, v in open_clip.create_model("ViT-B-32", pretrained=None).state_dict().items()},
               weights)
    env = {**__import__("os").environ, "HF_HUB_CACHE": str(tmp_path / "hub"), "HOME": str(tmp_path)}
    runs = []
    for name in ("clip", "auto"):
        proc = subprocess.run([sys.executable, "-c", _AUTO_TAG, str(tmp_path / "cache"), name], capture_output=True,
                              text=True, timeout=600, cwd=REPO, env=env)
        assert proc.returncode == 0, proc.stderr
        runs.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    first, second = runs
    for run in runs:
        assert run["weights"] == str(weights) and run["weights_source"] == "cache:laion2b_s34b_b79k"
        assert run["runtime"] == "onnx" and run["torch"] is False
    assert first["export_cached"] is False and set(first["children"]) == {"export", "texts"}
    assert second["export_cached"] is True and second["children"] == {}


def test_missing_weights_are_the_same_one_line_errors_as_with_torch(tmp_path):
    for cfg, start in ((EncoderConfig(name="clip", weights=str(tmp_path / "nope.pt")), "CLIP weights "),
                       (EncoderConfig(name="clip", weights=None, pretrained=None), "no CLIP weights for ViT-B-32")):
        with pytest.raises(MerlionError) as err:
            make_encoder(cfg.model_copy(update={"runtime": "onnx", "cache_dir": str(tmp_path / "cache")}))
        assert str(err.value).startswith(start) and "merlion models pull" in str(err.value)
        assert "\n" not in str(err.value)
