"""The BlueOS extension's Dockerfile labels and metadata.json, read as BlueOS's Extensions Repository reads them
(json5 labels: version, type, requirements, tags (up to 10, lower-case alphanumeric and dashes), authors, company,
readme, links, permissions as a Docker container-create body); and the image built from a Debian base
(make_base.sh, debootstrap + docker import) and started where a Docker daemon runs."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest

from companion import __version__
from companion.extension.metadata import PORT
from tests.conftest import REPO

HERE = REPO / "packaging" / "blueos"
TYPES = {"device-integration", "example", "theme", "other", "tool"}
DATA = "/usr/blueos/extensions/merlion"


def dockerfile_labels(path: Path) -> tuple[dict[str, str], dict[str, str], list[str]]:
    """(labels, build-arg defaults, CMD) of a Dockerfile, with continuation lines joined and ${ARG}s filled in."""
    text = re.sub(r"\\\n", "", path.read_text())
    labels, args, cmd = {}, {}, []
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("ARG "):
            name, _, default = line[4:].partition("=")
            args[name] = default
        elif line.startswith("LABEL "):
            for item in shlex.split(line[6:]):
                key, _, value = item.partition("=")
                labels[key] = re.sub(r"\$\{(\w+)\}", lambda m: args[m.group(1)], value)
        elif line.startswith("CMD "):
            cmd = json.loads(line[4:])
    return labels, args, cmd


def test_labels_are_what_the_extensions_repository_reads():
    labels, args, cmd = dockerfile_labels(HERE / "Dockerfile")
    assert labels["version"] == __version__
    assert labels["type"] in TYPES
    assert re.fullmatch(r"core >= \d+\.\d+(\.\d+)?", labels["requirements"])
    tags = json.loads(labels["tags"])
    assert 0 < len(tags) <= 10 and all(t == t.lower() and t.replace("-", "").isalnum() for t in tags)
    authors = json.loads(labels["authors"])
    assert authors and all(set(a) == {"name", "email"} for a in authors)
    company = json.loads(labels["company"])
    assert {"name", "about", "email"} <= set(company)
    # the Extensions Repository (blueos_repository/extension/extension.py) replaces "{tag}" with the version's tag
    assert labels["readme"].startswith(args["PROJECT_URL"]) and "{tag}" in labels["readme"]
    assert "{tag_name}" not in labels["readme"]
    links = json.loads(labels["links"])
    assert {"website", "support", "docs"} <= set(links) and links["website"] == args["PROJECT_URL"]

    permissions = json.loads(labels["permissions"])
    host = permissions["HostConfig"]
    assert host["NetworkMode"] == "host"  # BlueOS's helper finds the page on the vehicle's own port
    assert f"{DATA}:{DATA}" in host["Binds"]  # store, gallery and settings survive an update
    assert any(rule.startswith("c 81:") for rule in host["DeviceCgroupRules"])  # video4linux, when freed
    assert set(permissions["ExposedPorts"]) == {f"{PORT}/tcp"}  # the extension's port: none of BlueOS's
    assert cmd[:2] == ["merlion", "extension"] and cmd[cmd.index("--data") + 1] == DATA
    assert cmd[cmd.index("--port") + 1] == str(PORT)


def test_metadata_json_is_what_the_repository_expects():
    meta = json.loads((HERE / "metadata.json").read_text())
    assert set(meta) == {"name", "website", "docker", "description"}
    assert re.fullmatch(r"[a-z0-9._-]+/[a-z0-9._-]+", meta["docker"])
    labels, _, _ = dockerfile_labels(HERE / "Dockerfile")
    assert meta["website"] == json.loads(labels["links"])["website"]
    # the logo the repository takes from next to metadata.json (extension.py: repository / "../extension_logo.png")
    logo = (HERE / "extension_logo.png").read_bytes()
    assert logo[:8] == b"\x89PNG\r\n\x1a\n" and len(logo) < 64 * 1024


def docker_or_skip() -> str:
    docker = shutil.which("docker")
    if docker is None:
        pytest.skip("no docker client here: the image is built and started only where Docker runs")
    if subprocess.run([docker, "info"], capture_output=True, timeout=30).returncode != 0:
        pytest.skip("no Docker daemon here (dockerd absent or not running): image build and start not tried")
    if shutil.which("debootstrap") is None:
        pytest.skip("no debootstrap here: the base image is made from Debian's archive with it")
    return docker


@pytest.mark.slow
@pytest.mark.timeout(3600)  # PyPI's wheels (torch among them) are downloaded into the image
def test_image_builds_from_a_debian_base_and_serves_register_service():
    docker = docker_or_skip()
    arch = {"x86_64": "amd64", "aarch64": "arm64"}.get(subprocess.run(["uname", "-m"], capture_output=True,
                                                                       text=True).stdout.strip(), "amd64")
    have_base = subprocess.run([docker, "image", "inspect", "merlion-base:latest"], capture_output=True).returncode == 0
    if not have_base:  # debootstrap takes minutes: a base made before (by make_base.sh) is reused
        subprocess.run(["bash", str(HERE / "make_base.sh"), arch], check=True, timeout=1800)
    tag = f"merlion/blueos-merlion:{__version__}"
    local_cas = "".join(p.read_text() for p in sorted(Path("/usr/local/share/ca-certificates").glob("*.crt")))
    subprocess.run([docker, "build", "--network", "host", "--build-arg", f"EXTRA_CA_PEM={local_cas}",
                    "-f", str(HERE / "Dockerfile"), "-t", tag, str(REPO)], check=True, timeout=3600)
    labels = json.loads(subprocess.run([docker, "inspect", "--format", "{{json .Config.Labels}}", tag],
                                       capture_output=True, text=True, check=True).stdout)
    assert labels["version"] == __version__ and json.loads(labels["permissions"])["HostConfig"]["NetworkMode"] == "host"
    name = "merlion-extension-test"
    subprocess.run([docker, "rm", "-f", name], capture_output=True)
    subprocess.run([docker, "run", "-d", "--name", name, "--network", "host", tag, "merlion", "extension",
                    "--data", "/tmp/merlion", "--port", str(PORT), "--source", "synthetic://dive", "--no-companion"],
                   check=True)
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{PORT}/register_service", timeout=5) as r:
                    assert json.load(r)["works_in_relative_paths"] is True
                break
            except OSError:
                assert time.monotonic() < deadline, "the extension's page never answered"
                time.sleep(1)
    finally:
        subprocess.run([docker, "rm", "-f", name], capture_output=True)
