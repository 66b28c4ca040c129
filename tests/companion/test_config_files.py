"""The shipped YAML files: default.yaml equals the schema's defaults, every key is documented, the vehicle file is valid."""

from __future__ import annotations

from pathlib import Path

import yaml

from companion.config import Config, load_config
from tests.conftest import REPO

CONFIG = REPO / "config"


def test_default_yaml_equals_the_schema_defaults() -> None:
    data = yaml.safe_load((CONFIG / "default.yaml").read_text())
    defaults = Config().model_dump(mode="json")
    assert data == defaults, "config/default.yaml is out of step: run python scripts/config_reference.py"
    assert load_config(CONFIG / "default.yaml", environ={}) == Config()


def test_every_default_key_has_a_comment() -> None:
    lines = (CONFIG / "default.yaml").read_text().splitlines()
    for i, line in enumerate(lines):
        if line.startswith("  ") and not line.lstrip().startswith("#") and ":" in line:
            assert lines[i - 1].lstrip().startswith("#"), f"default.yaml line {i + 1} has no comment: {line.strip()}"


def test_configuration_reference_names_every_key() -> None:
    text = (REPO / "docs" / "configuration.md").read_text()
    for section, values in Config().model_dump().items():
        for key in values:
            assert f"`{section}.{key}`" in text, f"docs/configuration.md does not document {section}.{key}"


def test_vehicle_config_is_valid_and_is_the_vehicle_set_up(tmp_path: Path) -> None:
    cfg = load_config(CONFIG / "bluerov2-orin.yaml", environ={})
    assert cfg.source.uri.startswith("/dev/video") and cfg.source.fourcc == "MJPG"
    assert cfg.encoder.name == "clip" and cfg.encoder.model == "ViT-B-32" and cfg.encoder.device == "cuda"
    assert cfg.mavlink.connection.startswith(("tcp:", "udpin:", "udpout:"))
    assert cfg.mavlink.component_id not in (191, 194)
