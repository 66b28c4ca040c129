"""``vehicle/`` is a MAVLink package on its own: every module imports without the app."""

from __future__ import annotations

import subprocess
import sys

CHECK = """
import importlib, pkgutil, sys
import vehicle
names = [m.name for m in pkgutil.walk_packages(vehicle.__path__, "vehicle.")]
for name in names:
    importlib.import_module(name)
leaked = sorted(m for m in sys.modules if m == "companion" or m.startswith("companion."))
print(len(names), ",".join(leaked))
"""


def test_every_vehicle_module_imports_without_companion() -> None:
    out = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, check=True, timeout=120)
    count, leaked = out.stdout.strip().split(" ", 1) if " " in out.stdout.strip() else (out.stdout.strip(), "")
    assert int(count) >= 25  # link, autopilot, camera, protocol and sim modules were all walked
    assert leaked == ""
