"""Helpers for the live companion's tests: a real `merlion run` subprocess, a UDP hub, a MAVLink listener.

The companion runs as a real process on real loopback sockets; tests wait on its log lines and on files in
its store (with timeouts), never on fixed sleeps.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml
from pymavlink import mavftp, mavutil

from tests.conftest import REPO
from tests.waiting import wait_until as poll_until
from vehicle.sim.ground_listener import GroundListener as Listener  # one listener, the soak bench's too

FAST_SOURCE = "synthetic://dive?seconds=1&width=160&height=96"


def write_config(path: Path, **sections) -> Path:
    """A config file for a quick companion: the cheap visual encoder, a fast generated source."""
    data = {
        "source": {"uri": FAST_SOURCE, "fps": 10, "realtime": True, "retry_initial_s": 0.2, "retry_max_s": 0.5},
        "encoder": {"name": "visual"},
        "queries": {"tau_ss": 0.5},
        "surface": {"budget_bytes_per_s": 20000, "status_hz": 2},
        "health": {"stall_after_s": 30},
    }
    for key, value in sections.items():
        data.setdefault(key, {}).update(value)
    path.write_text(yaml.safe_dump(data))
    return path


_PR_SET_PDEATHSIG = 1
_started: list[Companion] = []
_started_lock = threading.Lock()


def _die_with_parent() -> None:
    """Runs in the child before exec: the kernel SIGKILLs it if the test process dies first (Linux only)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass


def reap_companions() -> None:
    """Kill every companion a test started and left running (a failed assertion skips its terminate())."""
    with _started_lock:
        started, _started[:] = list(_started), []
    for companion in started:
        companion.kill()


class Companion:
    """`merlion run` in a subprocess with its log collected line by line.

    Every instance is remembered so that the tests' teardown (``reap_companions``) kills it whatever the test
    did, and the child is tied to the test process so that not even a killed pytest leaves it running.
    """

    def __init__(self, *args: str, env: dict | None = None) -> None:
        full_env = dict(os.environ)
        full_env.update(env or {})
        full_env["PYTHONUNBUFFERED"] = "1"
        preexec = _die_with_parent if sys.platform.startswith("linux") else None
        self.proc = subprocess.Popen([sys.executable, "-m", "companion", "run", *args], cwd=REPO, env=full_env,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     preexec_fn=preexec)
        with _started_lock:
            _started.append(self)
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    @property
    def output(self) -> str:
        with self._cond:
            return "\n".join(self.lines)

    def wait_for(self, pattern: str, timeout: float = 60.0, start: int = 0) -> str:
        """The first log line (from line ``start``) matching ``pattern``; fails the test on timeout or exit."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for line in self.lines[start:]:
                    if rx.search(line):
                        return line
                if self.proc.poll() is not None and not self._reader.is_alive():
                    raise AssertionError(f"companion exited ({self.proc.returncode}) before {pattern!r}:\n"
                                         + "\n".join(self.lines[-40:]))
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no {pattern!r} within {timeout} s:\n" + "\n".join(self.lines[-40:]))
                self._cond.wait(min(left, 0.5))

    def mark(self) -> int:
        with self._cond:
            return len(self.lines)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def terminate(self, timeout: float = 60.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        finally:
            self._reader.join(timeout=5)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(30)
        self._reader.join(timeout=5)


def wait_until(predicate, timeout: float = 60.0, what: str = "condition") -> None:
    """Fails the test, naming ``what``, unless ``predicate()`` comes true within ``timeout`` seconds."""
    if not poll_until(predicate, timeout, interval=0.1):
        raise AssertionError(f"timed out waiting for {what}")


def store_summary(store: Path) -> dict:
    try:
        return json.loads((store / "summary.json").read_text())
    except (OSError, ValueError):
        return {}


@contextlib.contextmanager
def simulated_vehicle(**sim_options):
    """A UDP hub (the vehicle's router), the simulated ArduSub on it (``sim_options`` to SimVehicle) and a
    ground-station listener on it: (hub, sim, listener)."""
    from companion.live.udp_hub import UdpHub
    from vehicle.sim.vehicle import SimVehicle

    listener = Listener()
    hub = UdpHub(outputs=[("127.0.0.1", listener.port)]).start()
    sim = SimVehicle(hub.url, **sim_options)
    sim.start()
    try:
        yield hub, sim, listener
    finally:
        sim.stop()
        hub.stop()
        listener.close()


def write_clip(path: Path, frames: int = 20) -> Path:
    """A short MJPEG clip of the generated dive, for a live companion run on a file."""
    import cv2

    from companion.sources.synthetic import SyntheticSource

    source = SyntheticSource("synthetic://dive?seconds=1&width=160&height=96", fps=10, realtime=False)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 96))
    for i, frame in enumerate(source):
        if i >= frames:
            break
        writer.write(frame.image)
    writer.release()
    return path


def ground_ftp(gcs) -> mavftp.MAVFTP:
    """A pymavlink mavftp client of the ground station, with retry times fit for a busy loopback hub."""
    values = {"debug": 0, "pkt_loss_tx": 0, "pkt_loss_rx": 0, "max_backlog": 5, "burst_read_size": 239,
              "write_size": 80, "write_qsize": 5, "idle_detection_time": 1.5, "read_retry_time": 0.6,
              "retry_time": 0.4}
    return mavftp.MAVFTP(gcs, 1, 100, settings=mavftp.MAVFTPSettings([(k, type(v), v) for k, v in values.items()]))


def ftp_get_json(client: mavftp.MAVFTP, remote: str, local: Path) -> dict:
    """A JSON file fetched over MAVLink FTP, asked again when a reply is lost."""
    for _ in range(5):  # a reply can be lost on a busy hub; a ground station asks again
        local.unlink(missing_ok=True)
        client.cmd_get([remote, str(local)])
        if client.process_ftp_reply("OpenFileRO", timeout=15).error_code == mavftp.FtpError.Success:
            try:
                return json.loads(local.read_text())
            except (OSError, ValueError):
                continue
    raise AssertionError(f"could not fetch {remote}")


def ftp_put(client: mavftp.MAVFTP, local: Path, remote: str, done=None, tries: int = 3) -> None:
    """Upload ``local`` over MAVLink FTP, sent again while ``done(reply)`` is false (default: the put succeeded).

    The first request may reach the hub before it knows where the companion is. The caller checks the outcome
    itself (a refusal has no NAK on the close: mavftp does not report it, so ``done`` may look elsewhere).
    """
    for _ in range(tries):
        client.cmd_put([str(local), remote])
        reply = client.process_ftp_reply("put", timeout=15)
        if (done(reply) if done else reply.error_code == mavftp.FtpError.Success):
            return


def set_param(gcs, listener: Listener, name: str, value: float, integer: bool, expect: float | None = None):
    """PARAM_SET until the companion answers with ``expect`` (default: ``value``); returns that PARAM_VALUE."""
    kind = mavutil.mavlink.MAV_PARAM_TYPE_INT32 if integer else mavutil.mavlink.MAV_PARAM_TYPE_REAL32
    want = value if expect is None else expect
    start = len(listener.messages)
    for _ in range(5):  # the first one may reach the hub before it knows where the companion is
        gcs.mav.param_set_send(1, 100, name.encode(), float(value), kind)
        try:
            return listener.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name
                                     and abs(m.param_value - want) < 1e-6 and m in listener.messages[start:], 5,
                                     f"{name} echo")
        except AssertionError:
            continue
    raise AssertionError(f"{name}={value} never answered with {want}")
