"""`merlion install-service`: put the systemd unit, a config and the service user in place."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(add_command) -> None:
    p = add_command("install-service", "install the systemd unit (Type=notify, watchdog) so the companion starts at boot")
    p.add_argument("--config", type=Path, help="config to install as /etc/merlion/companion.yaml "
                   "(default: config/bluerov2-orin.yaml when none is installed yet)")
    p.add_argument("--user", default="merlion", help="service user (created as a system user; default merlion)")
    p.add_argument("--root", type=Path, default=Path("/"), help="stage under this directory instead of / "
                   "(no user is created, systemctl is not run)")
    p.add_argument("--no-enable", action="store_true", help="do not enable the unit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.live.service import InstallPlan, install

    for line in install(InstallPlan(root=args.root, user=args.user, config=args.config, enable=not args.no_enable)):
        print(line)
    print("start it with: sudo systemctl start merlion-companion; watch it with: journalctl -fu merlion-companion")
    return 0
