"""The rate keeper's answers come from the autopilot alone, on real loopback sockets: with a signing key, an
unsigned peer (another component of the autopilot's system) flooding COMMAND_ACKs "SET_MESSAGE_INTERVAL
unsupported" at the companion must not make it give up on SET_MESSAGE_INTERVAL while the signing autopilot accepts
it (issue 48: no unsigned message moves the rate keeper's decisions)."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.config import MavlinkConfig
from tests.conftest import free_udp_port
from tests.vehicle.tether import KEY, PASSPHRASE, Peer, Repeater, sub_heartbeat
from tests.waiting import wait_until
from vehicle.link.connection import MavLink
from vehicle.link.message_rates import RateKeeper


def test_an_unsigned_peers_command_ack_is_not_the_autopilots_answer(tmp_path) -> None:
    key_file = tmp_path / "signing.key"
    key_file.write_text(PASSPHRASE + "\n")
    port = free_udp_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", MavlinkConfig(signing_key_file=str(key_file), component_id=100))
    autopilot = Peer(port, 1, 1, KEY)
    spoofer = Peer(port, 1, 2)
    refusal = mav2.MAVLink_command_ack_message(mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAV_RESULT_UNSUPPORTED,
                                               0, 0, 1, 100)
    beats = flood = None
    keeper = RateKeeper(link, {"ATTITUDE": 10.0}, ack_timeout_s=5.0, retries=0, listen_s=0.0)
    link.start()
    try:
        beats = Repeater(autopilot, lambda: [sub_heartbeat()], 10.0)
        assert link.wait_autopilot(10)
        assert link.autopilot == (1, 1)
        flood = Repeater(spoofer, lambda: [refusal], 100.0)
        keeper.start()
        asked = wait_until(lambda: autopilot.got("COMMAND_LONG", cond=lambda m: m.command
                                                 == mav2.MAV_CMD_SET_MESSAGE_INTERVAL), timeout=10)
        assert asked, "the keeper never asked the autopilot for ATTITUDE"
        autopilot.send(mav2.MAVLink_command_ack_message(mav2.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                        mav2.MAV_RESULT_ACCEPTED, 0, 0, 1, 100))
        assert wait_until(lambda: "ATTITUDE" in keeper.method, timeout=10)
        assert flood.sent > 0
        assert keeper.acks["ATTITUDE"] == mav2.MAV_RESULT_ACCEPTED
        assert keeper.method["ATTITUDE"] == "interval"
        assert keeper.requests["ATTITUDE"] == 1
    finally:
        for repeater in (flood, beats):
            if repeater is not None:
                repeater.stop()
        keeper.stop()
        link.stop()
        autopilot.close()
        spoofer.close()
