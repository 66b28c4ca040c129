"""The one table from request type to handler on the companion's camera component, and the one "is it for us".

Each MAVLink request type the component answers is routed here once: the handler and the worker thread it runs
on (FTP on one, commands and parameters on another), whether a broadcast (target component 0) may address it, and
whether it counts against the requester's rate (``RequestGate``). The receive loop calls the router, which checks
the target once (``addressed_to``), drops a flooding requester's excess, and hands the message to its worker;
adding a handler is one ``route`` call (``Downlink.handle_requests`` for one that answers with messages).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav

from vehicle.camera.request_worker import RequestWorker
from vehicle.link.fair_replies import Requester
from vehicle.link.request_gate import RequestGate


def addressed_to(msg: mav.MAVLink_message, me: tuple[int, int], *, broadcast: bool = True) -> bool:
    """Whether ``msg`` targets ``me`` (system, component): its system or every system, and its component or, when
    ``broadcast``, every component. ``target`` (MANUAL_CONTROL's name for the system) counts as the system."""
    system = getattr(msg, "target_system", getattr(msg, "target", 0))
    component = getattr(msg, "target_component", 0)
    if system not in (0, me[0]):
        return False
    return component == me[1] or (broadcast and component == 0)


def requester(msg: mav.MAVLink_message) -> Requester:
    """Who asked: the sender's ids and whether its request was signed (ids can be spoofed, a signature cannot)."""
    return msg.get_srcSystem(), msg.get_srcComponent(), bool(getattr(msg, "_signed", False))


@dataclass(frozen=True)
class Route:
    handler: Callable[[mav.MAVLink_message], None]
    worker: RequestWorker
    broadcast: bool
    gated: bool


class RequestRouter:
    """Message type -> ``Route``; call it with each received message (on the receive loop: it only hands off)."""

    def __init__(self, me: Callable[[], tuple[int, int]], gate: RequestGate | None = None) -> None:
        self._me = me
        self._gate = gate
        self._routes: dict[str, Route] = {}
        self.not_for_us = 0

    def route(self, mtype: str, handler: Callable[[mav.MAVLink_message], None], worker: RequestWorker, *,
              broadcast: bool = True, gated: bool = True) -> None:
        """Run ``handler(msg)`` on ``worker`` for each ``mtype`` addressed to us (to every component too, when
        ``broadcast``); ``gated``: one of the requests each requester may make only so many of per second."""
        self._routes[mtype] = Route(handler, worker, broadcast, gated)

    @property
    def types(self) -> tuple[str, ...]:
        return tuple(self._routes)

    def for_us(self, msg: mav.MAVLink_message) -> bool:
        """Whether a request of a routed type is addressed to this component (False for unrouted types)."""
        route = self._routes.get(msg.get_type())
        return route is not None and addressed_to(msg, self._me(), broadcast=route.broadcast)

    def __call__(self, msg: mav.MAVLink_message) -> None:
        route = self._routes.get(msg.get_type())
        if route is None:
            return
        if not addressed_to(msg, self._me(), broadcast=route.broadcast):
            self.not_for_us += 1
            return
        if route.gated and self._gate is not None and not self._gate.admit(requester(msg)):
            return
        route.worker.submit(lambda: route.handler(msg), signed=requester(msg)[2])
