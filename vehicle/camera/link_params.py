"""The surface link's own parameters: the thumbnail byte budget and the link's byte rate.

They belong to the ``Downlink``, which serves and applies them whether or not an app adds parameters of its own
(the vehicle camera alone, a simulator, the companion): one owner, one place each change takes effect.
"""

from __future__ import annotations

from vehicle.camera.params import ParamSpec
from vehicle.settings import SurfaceConfig

THUMB_B = "MERL_THUMB_B"
LINK_BPS = "MERL_LINK_BPS"
NAMES = (THUMB_B, LINK_BPS)


def link_params(cfg: SurfaceConfig) -> list[ParamSpec]:
    """The two as served, starting from the link's configuration."""
    return [
        ParamSpec.around(THUMB_B, cfg.thumbnail_bytes, 300, 65000, integer=True, doc="thumbnail byte budget"),
        ParamSpec.around(LINK_BPS, cfg.budget_bytes_per_s, 100, 1_000_000, integer=True, doc="link budget, bytes/s"),
    ]
