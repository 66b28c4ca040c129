"""``VehicleGuard`` on its own: a page of the vehicle is one of its names at any port, or one of its IP addresses
as they are at the time of the request (an interface may get its address after the extension started), and
nothing else; what it lets frame the pages follows the same addresses."""

from __future__ import annotations

import ipaddress

from companion.extension.vehicle_guard import VehicleGuard, own_addresses, vehicle_names


def test_an_address_the_vehicle_gets_later_is_its_page_from_then_on():
    addresses = ["127.0.0.1", "192.168.2.2"]
    guard = VehicleGuard(vehicle_names(), addresses=lambda: list(addresses))
    later = {"Origin": "http://10.4.0.7"}  # a Wi-Fi lease after start-up
    assert guard.change_refusal(later, "/api/mark") is not None
    assert "http://10.4.0.7:*" not in guard.frame_ancestors().split()
    addresses.append("10.4.0.7")
    assert guard.change_refusal(later, "/api/mark") is None
    assert guard.change_refusal({"Origin": "http://10.4.0.7:8000"}, "/api/mark") is None  # Cockpit's port
    assert guard.read_refusal({"Referer": "http://10.4.0.7/extensionv2/merlioncompanion/"}) is None
    assert "http://10.4.0.7:*" in guard.frame_ancestors().split()
    addresses.remove("10.4.0.7")  # the lease gone (perhaps to another machine): no longer the vehicle
    assert guard.change_refusal(later, "/api/mark") is not None


def test_names_at_any_port_and_nothing_else():
    guard = VehicleGuard(vehicle_names(["rov7"]), addresses=lambda: ["192.168.2.2"])
    for origin in ("http://blueos-wifi.local", "http://BLUEOS.local:8000", "https://companion.local:443",
                   "http://rov7", "http://192.168.2.2:6040"):
        assert guard.change_refusal({"Origin": origin}, "/api/topic") is None, origin
    for origin in ("http://stranger.example", "null", "http://blueos.local.stranger.example",
                   "http://192.168.2.3", "file://", "http://[::2]"):
        assert guard.change_refusal({"Origin": origin}, "/api/topic") is not None, origin
    assert guard.change_refusal({}, "/api/topic") is not None  # a change names its page
    assert guard.change_refusal({"Referer": "http://blueos.local/"}, "/api/topic") is not None  # Origin only


def test_own_addresses_are_this_machines():
    found = own_addresses()
    assert "127.0.0.1" in found
    for address in found:
        ipaddress.ip_address(address)  # each an address, IPv6 without its zone
