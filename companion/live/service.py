"""Put the systemd unit in place: the packaged unit with this installation's paths, a config, a service user.

``root`` stages everything under another directory (for images built off the vehicle, and for tests) and then
skips what only makes sense on the live system (creating the user, systemctl).
"""

from __future__ import annotations

import logging
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from companion.errors import MerlionError, UsageError
from companion.packaged import config_file, unit_template

log = logging.getLogger(__name__)

UNIT_NAME = "merlion-companion.service"
UNIT_TEMPLATE = unit_template(UNIT_NAME)
VEHICLE_CONFIG = config_file("bluerov2-orin.yaml")
"""Both are package data (companion/packaged/), so an installed wheel has them; no checkout is needed."""
USER_NAME = re.compile(r"[a-z_][a-z0-9_-]{0,31}")
"""What useradd accepts by default; anything else would also break the User= line of the unit."""


@dataclass
class InstallPlan:
    root: Path = Path("/")
    user: str = "merlion"
    config: Path | None = None
    """Config to install as /etc/merlion/companion.yaml (default: the BlueROV2/Orin one, if none is there)."""
    merlion: str | None = None
    """The merlion executable (default: the one on PATH, else this Python with -m companion)."""
    enable: bool = True
    done: list[str] = field(default_factory=list)


def merlion_command() -> str:
    """This installation's own ``merlion`` (beside its Python: a venv need not be on PATH), else the one on PATH,
    else this Python with -m companion."""
    own = Path(sys.executable).parent / "merlion"
    if own.is_file():
        return str(own)
    found = shutil.which("merlion")
    return found if found else f"{sys.executable} -m companion"


def render_unit(template: str, *, exec_start: str, config_path: str, user: str) -> str:
    text = re.sub(r"^ExecStart=.*$", f"ExecStart={exec_start} run --config {config_path}", template, flags=re.M)
    text = re.sub(r"^User=.*$", f"User={user}", text, flags=re.M)
    return re.sub(r"^Group=.*$", f"Group={user}", text, flags=re.M)


def install(plan: InstallPlan) -> list[str]:
    """Write the unit and config; on the live system also create the user and enable the service."""
    if not UNIT_TEMPLATE.is_file():
        raise MerlionError(f"{UNIT_TEMPLATE}: unit template missing from this installation")
    if not USER_NAME.fullmatch(plan.user):
        raise UsageError(f"--user {plan.user!r}: not a valid user name (lower-case letters, digits, _ and -)")
    live = plan.root == Path("/")
    unit_dir = plan.root / "etc" / "systemd" / "system"
    conf_dir = plan.root / "etc" / "merlion"
    conf_path = conf_dir / "companion.yaml"
    try:
        unit_dir.mkdir(parents=True, exist_ok=True)
        conf_dir.mkdir(parents=True, exist_ok=True)
        if plan.config is not None or not conf_path.exists():
            if plan.config is not None:
                if not plan.config.is_file():
                    raise UsageError(f"{plan.config}: no such config file")
                shutil.copyfile(plan.config, conf_path)
                source = str(plan.config)
            else:
                conf_path.write_bytes(VEHICLE_CONFIG.read_bytes())
                source = f"packaged {VEHICLE_CONFIG.name}"
            plan.done.append(f"config {source} -> {conf_path}")
        else:
            plan.done.append(f"config {conf_path} kept")
        unit = render_unit(UNIT_TEMPLATE.read_text(), exec_start=plan.merlion or merlion_command(),
                           config_path="/etc/merlion/companion.yaml", user=plan.user)
        (unit_dir / UNIT_NAME).write_text(unit)
        plan.done.append(f"unit -> {unit_dir / UNIT_NAME}")
    except PermissionError as err:
        raise MerlionError(f"{err.filename}: permission denied (run with sudo, or use --root DIR to stage)") from None
    except OSError as err:
        raise MerlionError(f"{err.filename or plan.root}: cannot write there ({err.strerror or err})") from None
    if live:
        _ensure_user(plan)
        _systemctl(plan, "daemon-reload")
        if plan.enable:
            _systemctl(plan, "enable", UNIT_NAME)
    return plan.done


def _ensure_user(plan: InstallPlan) -> None:
    if subprocess.run(["id", "-u", plan.user], capture_output=True).returncode == 0:
        plan.done.append(f"user {plan.user} exists")
        return
    done = subprocess.run(["useradd", "--system", "--no-create-home", "--groups", "video,dialout",
                           "--shell", "/usr/sbin/nologin", plan.user], capture_output=True, text=True)
    if done.returncode != 0:
        raise MerlionError(f"useradd {plan.user}: {done.stderr.strip() or 'failed'}")
    plan.done.append(f"user {plan.user} created (groups video, dialout)")


def _systemctl(plan: InstallPlan, *args: str) -> None:
    if shutil.which("systemctl") is None:
        plan.done.append(f"systemctl {' '.join(args)}: skipped (no systemctl here)")
        return
    done = subprocess.run(["systemctl", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise MerlionError(f"systemctl {' '.join(args)}: {done.stderr.strip() or 'failed'}")
    plan.done.append(f"systemctl {' '.join(args)}")
