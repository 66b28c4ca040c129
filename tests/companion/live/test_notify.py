"""sd_notify over a real AF_UNIX datagram socket, and the health check that gates the watchdog."""

from __future__ import annotations

import os
import socket
from pathlib import Path

from companion.live.health import Health
from companion.live.notify import Notifier


def listener(tmp_path: Path) -> tuple[socket.socket, str]:
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5)
    return sock, path


def test_ready_watchdog_and_status_reach_the_socket(tmp_path: Path) -> None:
    sock, path = listener(tmp_path)
    notifier = Notifier.from_environ({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "4000000",
                                      "WATCHDOG_PID": str(os.getpid())})
    assert notifier.enabled and notifier.ping_interval_s == 2.0
    assert notifier.ready("summary 0/6")
    assert sock.recv(4096).decode().split("\n") == ["READY=1", "STATUS=summary 0/6"]
    assert notifier.watchdog()
    assert sock.recv(4096) == b"WATCHDOG=1"
    assert notifier.status("x" * 500)
    assert len(sock.recv(4096)) == len("STATUS=") + 200
    notifier.close()
    sock.close()


def test_abstract_namespace_socket() -> None:
    name = f"merlion-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(5)
    notifier = Notifier.from_environ({"NOTIFY_SOCKET": "@" + name})
    assert notifier.watchdog()
    assert sock.recv(64) == b"WATCHDOG=1"
    sock.close()


def test_outside_systemd_nothing_is_sent() -> None:
    notifier = Notifier.from_environ({})
    assert not notifier.enabled and notifier.ping_interval_s is None
    assert notifier.ready() is False and notifier.watchdog() is False and notifier.sent == 0


def test_watchdog_for_another_pid_is_ignored(tmp_path: Path) -> None:
    notifier = Notifier.from_environ({"NOTIFY_SOCKET": str(tmp_path / "x"), "WATCHDOG_USEC": "1000000",
                                      "WATCHDOG_PID": "1"})
    assert notifier.watchdog_s is None


def test_a_gone_socket_is_reported_not_raised(tmp_path: Path, caplog) -> None:
    notifier = Notifier(str(tmp_path / "nobody-listens.sock"))
    assert notifier.ready() is False and notifier.watchdog() is False
    assert caplog.text.count("sd_notify") == 1


def test_health_flags_a_stuck_stage_and_recovers() -> None:
    now = [100.0]
    health = Health(10.0, clock=lambda: now[0])
    health.register("capture")
    health.register("inference")
    now[0] += 6
    health.beat("capture")
    now[0] += 6
    assert health.stuck() == ["inference"] and not health.healthy()
    health.beat("inference")
    assert health.healthy()
    now[0] += 11
    health.forget("capture")
    assert health.stuck() == ["inference"]


def run_with_notify(tmp_path: Path, source: str, stall_after_s: float):
    from tests.companion.live_harness import Companion, write_config

    sock, path = listener(tmp_path)
    cfg = write_config(tmp_path / "c.yaml", source={"uri": source}, mavlink={"connection": None},
                       health={"stall_after_s": stall_after_s}, store={"dir": str(tmp_path / "store")})
    companion = Companion("--config", str(cfg), env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "1000000"})
    return sock, companion


def receive(sock: socket.socket) -> list[str]:
    out = []
    sock.settimeout(0.05)
    while True:
        try:
            out.extend(sock.recv(4096).decode().split("\n"))
        except TimeoutError:
            return out


def test_companion_sends_ready_watchdog_and_status_to_systemd(tmp_path: Path) -> None:
    from tests.companion.live_harness import wait_until

    sock, companion = run_with_notify(tmp_path, "synthetic://dive?seconds=1&width=160&height=96", 30)
    got: list[str] = []
    try:
        wait_until(lambda: got.extend(receive(sock)) or got.count("WATCHDOG=1") >= 2, 60, "two watchdog pings")
        assert "READY=1" in got and got.index("READY=1") < got.index("WATCHDOG=1")
        assert any(line.startswith("STATUS=") and "summary" in line for line in got)
        assert companion.terminate() == 0
        got.extend(receive(sock))
        assert "STOPPING=1" in got
    finally:
        companion.kill()
        sock.close()


def test_a_stuck_stage_stops_the_watchdog_pings(tmp_path: Path) -> None:
    from tests.companion.live_harness import wait_until
    from tests.conftest import free_udp_port

    # an RTP stream nobody sends: the capture stage blocks inside the decoder, as a wedged camera driver would
    sock, companion = run_with_notify(tmp_path, f"udp://127.0.0.1:{free_udp_port()}", 1)
    got: list[str] = []
    try:
        wait_until(lambda: got.extend(receive(sock)) or "READY=1" in got, 60, "READY=1")
        companion.wait_for("capture stuck", 60)
        receive(sock)  # what was sent before the monitor saw it stuck
        later: list[str] = []
        wait_until(lambda: later.extend(receive(sock)) or sum(x.startswith("STATUS=") for x in later) >= 2, 60,
                   "two status updates while stuck")
        first_two = later[: [i for i, x in enumerate(later) if x.startswith("STATUS=")][1] + 1]
        assert "WATCHDOG=1" not in first_two
    finally:
        companion.kill()
        sock.close()
