"""Files that travel inside the package: the systemd unit and the YAML configurations.

They live at the top of the repository (``systemd/``, ``config/``: the team's map); the two links here put them in
the package, so an installed wheel has them and nothing reads the repository checkout at run time.
"""

from __future__ import annotations

from importlib import resources
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # importlib.abc's name is deprecated from 3.12, importlib.resources.abc's is new in 3.11
    from importlib.abc import Traversable


def unit_template(name: str) -> Traversable:
    """The systemd unit ``name`` as shipped."""
    return resources.files(__name__).joinpath("systemd", name)


def config_file(name: str) -> Traversable:
    """A shipped configuration, e.g. ``bluerov2-orin.yaml``."""
    return resources.files(__name__).joinpath("config", name)
