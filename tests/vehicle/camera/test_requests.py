"""The downlink's one request table (issue 26 item 3, vehicle side), on real UDP: the target is checked once,
before any worker is bothered, and a new MAVLink handler is one ``handle_requests`` call."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.conftest import free_udp_port
from tests.vehicle.surface_env import companion_link
from tests.vehicle.tether import Peer, gcs_heartbeat
from tests.waiting import wait_until
from vehicle.camera.downlink import Downlink
from vehicle.camera.requests import addressed_to
from vehicle.settings import SurfaceConfig

COMPANION = (1, 100)


def test_addressing_is_decided_in_one_place():
    ping = mav2.MAVLink_param_request_list_message
    assert addressed_to(ping(1, 100), COMPANION) and addressed_to(ping(0, 0), COMPANION)
    assert not addressed_to(ping(1, 1), COMPANION) and not addressed_to(ping(2, 100), COMPANION)
    assert not addressed_to(ping(1, 0), COMPANION, broadcast=False)
    assert not addressed_to(mav2.MAVLink_manual_control_message(2, 0, 0, 500, 0, 0), COMPANION)  # `target`


def test_a_new_handler_is_one_route_and_requests_for_others_never_reach_a_worker():
    port = free_udp_port()
    link = companion_link(port)
    surface = Downlink(link, SurfaceConfig(budget_bytes_per_s=60000, push=False))
    seen = []

    def ping(msg):
        seen.append(msg)
        return [mav2.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent())]

    surface.handle_requests("PING", ping)
    surface.start()
    gcs = Peer(port, 255, 190)
    try:
        gcs.send(gcs_heartbeat())
        for target in ((1, 1), (2, 100), (1, 100)):  # the autopilot's, another vehicle's, ours
            gcs.send(mav2.MAVLink_ping_message(7, target[1], *target))
            gcs.send(mav2.MAVLink_command_long_message(*target, mav2.MAV_CMD_REQUEST_MESSAGE, 0, 259, 0, 0, 0, 0,
                                                       0, 0))
        assert wait_until(lambda: gcs.got("PING", COMPANION), 5)
        assert wait_until(lambda: gcs.got("COMMAND_ACK", COMPANION), 5)
        assert wait_until(lambda: surface.router.not_for_us == 4, 5)
        assert [m.seq for m in seen] == [100]
        assert surface.control_worker.served == 2  # our PING and our COMMAND_LONG only
    finally:
        surface.stop()
        link.stop()
        gcs.close()
