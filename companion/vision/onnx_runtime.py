"""ONNX Runtime, which the base install does not bring (``pip install "merlion-companion[onnx]"``): imported only
in a process that runs an ONNX model, and its absence is one line naming the setting that asked for it."""

from __future__ import annotations

from types import ModuleType

from companion.errors import UsageError


def onnxruntime(wanted_by: str) -> ModuleType:
    """The ``onnxruntime`` module; ``wanted_by`` names the setting or file that needs it, for the error."""
    try:
        import onnxruntime as ort  # 0.15 s and its memory (measured): only where an ONNX model runs
    except ImportError:
        raise UsageError(f"{wanted_by} needs ONNX Runtime, which the base install does not bring: "
                         f'pip install "merlion-companion[onnx]"') from None
    return ort
