"""The classic enhancer, its guided filter, the factory, and file/folder/video enhancement on disk."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.bench.enhance_bench import read_pairs, synthetic_murky_frames
from companion.config import EnhanceConfig
from companion.errors import MerlionError, UsageError
from companion.vision import image_quality as iq
from companion.vision.enhancers.classic import ClassicEnhancer, guided_filter
from companion.vision.enhancers.factory import make_enhancer
from companion.vision.enhancers.files import enhance_path
from tests.conftest import shared_file


def _murky(size=(160, 120), seed=0) -> np.ndarray:
    return synthetic_murky_frames(1, size, seed)[0]


def test_guided_filter_hand_cases():
    rng = np.random.default_rng(0)
    src = rng.random((40, 50), dtype=np.float32)
    # Guided by itself with a tiny eps it keeps the image (edge-preserving, here every "edge" is kept).
    assert np.allclose(guided_filter(src, src, 3, 1e-8), src, atol=1e-3)
    # A flat guide carries no edges: the result is the box mean of the box means of src.
    flat = np.full_like(src, 0.5)
    box = cv2.boxFilter(src, -1, (7, 7), borderType=cv2.BORDER_REFLECT)
    expected = cv2.boxFilter(box, -1, (7, 7), borderType=cv2.BORDER_REFLECT)
    assert np.allclose(guided_filter(flat, src, 3, 1e-3), expected, atol=1e-5)


@pytest.mark.parametrize("shape", [(5, 7), (120, 160), (271, 481), (480, 640)])
def test_classic_keeps_size_and_type(shape):
    img = _murky((shape[1], shape[0]))
    out = ClassicEnhancer().enhance(img)
    assert out.shape == img.shape and out.dtype == np.uint8


def test_classic_refuses_non_bgr():
    with pytest.raises(ValueError, match="BGR uint8"):
        ClassicEnhancer().enhance(np.zeros((10, 10), np.uint8))


@pytest.mark.parametrize("balance", ["gray-world", "white-patch"])
def test_classic_reduces_the_blue_green_cast(balance):
    img = _murky()
    out = ClassicEnhancer(white_balance=balance).enhance(img)

    def cast(x):  # spread of the channel means: 0 for a neutral image
        m = x.reshape(-1, 3).mean(axis=0)
        return float(m.max() - m.min())

    assert cast(out) < 0.6 * cast(img)
    assert iq.uciqe(out) > iq.uciqe(img)


def test_classic_rejects_unknown_balance():
    with pytest.raises(ValueError, match="white_balance"):
        ClassicEnhancer(white_balance="purple")


def test_classic_raises_no_reference_quality_on_real_murky_pairs():
    pairs = read_pairs(shared_file("euvp_pairs"))
    enh = ClassicEnhancer()
    raw = [deg for _, deg, _ in pairs]
    out = [enh.enhance(d) for d in raw]
    assert np.mean([iq.uciqe(o) for o in out]) > np.mean([iq.uciqe(r) for r in raw])
    assert np.mean([iq.uiqm(o) for o in out]) > np.mean([iq.uiqm(r) for r in raw])


def test_factory_builds_classic_and_names_the_key_for_a_bad_model():
    assert isinstance(make_enhancer(EnhanceConfig()), ClassicEnhancer)
    with pytest.raises(MerlionError, match=r"^enhance\.model_path: required"):
        make_enhancer(EnhanceConfig(method="model"))
    with pytest.raises(MerlionError, match=r"enhance\.model_path: no such file: /nowhere/net\.onnx"):
        make_enhancer(EnhanceConfig(method="model", model_path="/nowhere/net.onnx"))


def test_enhance_folder_keeps_names_and_skips_unreadable(tmp_path):
    src = tmp_path / "raw"
    src.mkdir()
    for i in range(3):
        cv2.imwrite(str(src / f"f{i}.png"), _murky(seed=i))
    (src / "broken.jpg").write_bytes(b"not a jpeg")
    (src / "notes.txt").write_text("ignored")
    report = enhance_path(ClassicEnhancer(), src, tmp_path / "out", sbs=True, progress=False)
    assert sorted(p.name for p in report.written) == ["f0.png", "f1.png", "f2.png"]
    assert [p.name for p, _ in report.failed] == ["broken.jpg"]
    out = cv2.imread(str(tmp_path / "out" / "f1.png"))
    assert out.shape == (120, 320, 3)  # side by side: twice as wide
    assert np.array_equal(out[:, :160], _murky(seed=1))  # left half is the raw frame


def test_enhance_refuses_to_overwrite_input(tmp_path):
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), _murky())
    before = img.read_bytes()
    with pytest.raises(UsageError, match="would overwrite an input"):
        enhance_path(ClassicEnhancer(), img, img, progress=False)
    with pytest.raises(UsageError, match="would overwrite an input"):
        enhance_path(ClassicEnhancer(), tmp_path, tmp_path, progress=False)
    assert img.read_bytes() == before


def test_enhance_video_frame_for_frame(tmp_path):
    src = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(src), cv2.VideoWriter_fourcc(*"mp4v"), 10, (96, 64))
    for i in range(6):
        writer.write(_murky((96, 64), seed=i))
    writer.release()
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    report = enhance_path(ClassicEnhancer(), src, out_dir, progress=False)
    assert report.frames == 6 and report.written == [out_dir / "clip.mp4"]
    cap = cv2.VideoCapture(str(out_dir / "clip.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 6
    assert (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))) == (96, 64)
    cap.release()
    assert not list(out_dir.glob(".*partial*"))


def test_separation_report_on_real_stills_with_the_packaged_encoder(shared_data):
    from companion.bench.enhance_bench import load_labelled, separation_report
    from companion.config import EncoderConfig, QueryConfig
    from companion.vision.encoders.imagenet import ImageNetEncoder

    sets = load_labelled(shared_data, names=("suim",))
    assert [s.name for s in sets] == ["suim"] and int(sets[0].fish.sum()) == 4
    report = separation_report(ImageNetEncoder(EncoderConfig(device="cpu", batch=8)), QueryConfig(),
                               ClassicEnhancer(), sets, tau_ses=0.7)
    for key in ("suim", "all"):
        for which in ("raw", "enhanced"):
            assert 0.0 <= report[key][which]["auroc"] <= 1.0
    assert report["suim"]["raw"] == report["all"]["raw"]
    # Raw SUIM scores rank fish stills above empty ones (the encoder works); the enhanced figure is reported.
    assert report["suim"]["raw"]["auroc"] > 0.5
    kept = report["suim"]["filter_selective"]
    raw_kept = report["suim"]["filter_raw"]
    assert kept["fish_kept"] <= raw_kept["fish_kept"] and kept["nofish_kept"] <= raw_kept["nofish_kept"]
