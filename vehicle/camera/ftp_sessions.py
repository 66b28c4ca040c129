"""Who holds the FTP server's open files, and who may take a session when the table is full.

A session belongs to the link that opened it: the requester's (system, component) ids *and* whether its request
was signed. Ids are spoofable, a signature is not, so an unsigned request carrying a signed client's ids cannot
read, replace, end or burst that client's session (the server NAKs it and the owner never notices). Each
requester holds at most ``per_requester`` sessions (a new open closes its own oldest: it abandoned it); with
``reserve_signed``, unsigned requesters together hold at most ``max_sessions - reserve_signed``, so strangers on
the tether can never lock a signed client out. When the table is full a session is reclaimed in this order: the
opener's own oldest, for a signed opener the least recently used unsigned one, then the least recently used one
idle for ``idle_s`` (a session whose burst is still being sent is not idle).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass

log = logging.getLogger(__name__)

Requester = tuple[int, int]
"""(system id, component id) of the client; replies are addressed to it."""

IDLE_S = 5.0
"""A session untouched this long (no request, no burst packet) may be reclaimed for another client's open: a
client that is downloading asks again within a round trip."""


@dataclass
class Session:
    requester: Requester
    path: str
    data: bytearray
    writing: bool
    signed: bool = False
    burst_offset: int | None = None
    burst_seq: int = 0
    burst_left: int = 0
    burst_session: int = 0
    used: float = 0.0


class SessionTable:
    """The open sessions, keyed by (requester, session number); the caller holds the server's lock."""

    def __init__(self, max_sessions: int, *, per_requester: int = 2, reserve_signed: int = 0,
                 idle_s: float = IDLE_S) -> None:
        self.max_sessions = max_sessions
        self.per_requester = max(1, per_requester)
        self.reserve_signed = min(reserve_signed, max_sessions - 1)
        self.idle_s = idle_s
        self._sessions: OrderedDict[tuple[Requester, int], Session] = OrderedDict()
        self.refused_foreign = 0
        """Requests on a session that another link (a signed one, with the same ids) owns: refused."""
        self.reclaimed = 0

    def __len__(self) -> int:
        return len(self._sessions)

    def values(self) -> list[Session]:
        """Signed sessions first (their bursts are served first), each group oldest first."""
        sessions = list(self._sessions.values())
        return [s for s in sessions if s.signed] + [s for s in sessions if not s.signed]

    def find(self, who: Requester, number: int, signed: bool, now: float) -> tuple[Session | None, bool]:
        """(the session, False), or (None, True) when it belongs to a signed link and the request is unsigned."""
        sess = self._sessions.get((who, number))
        if sess is None:
            return None, False
        if sess.signed and not signed:
            self.refused_foreign += 1
            return None, True
        sess.used = now
        return sess, False

    def end(self, who: Requester, number: int) -> None:
        self._sessions.pop((who, number), None)

    def reset(self, who: Requester, signed: bool) -> None:
        """A client's ResetSessions: its sessions end (an unsigned one cannot end a signed link's)."""
        for key in [k for k, s in self._sessions.items() if k[0] == who and (signed or not s.signed)]:
            del self._sessions[key]

    def clear(self) -> None:
        self._sessions.clear()

    def grant(self, who: Requester, number: int, signed: bool, session: Session, now: float) -> str | None:
        """Open ``session`` as ``number`` for ``who``; None when granted, else why not: "foreign" (the number is a
        signed link's and the opener is unsigned) or "full" (no session can be had)."""
        key = (who, number)
        held = self._sessions.get(key)
        if held is not None and held.signed and not signed:
            self.refused_foreign += 1
            return "foreign"
        self._sessions.pop(key, None)
        own = [k for k, s in self._sessions.items() if k[0] == who and s.signed == signed]
        while len(own) >= self.per_requester:
            del self._sessions[own.pop(0)]
        if not signed and self.reserve_signed:
            unsigned = [k for k, s in self._sessions.items() if not s.signed]
            if len(unsigned) >= self.max_sessions - self.reserve_signed and not self._reclaim(unsigned, now):
                return "full"
        while len(self._sessions) >= self.max_sessions:
            if not self._make_room(who, signed, now):
                log.info("FTP: all %d sessions in use, refusing an open from %s", self.max_sessions, who)
                return "full"
        session.signed, session.used = signed, now
        self._sessions[key] = session
        return None

    def _make_room(self, who: Requester, signed: bool, now: float) -> bool:
        own = [k for k, s in self._sessions.items() if k[0] == who and (signed or not s.signed)]
        if own:
            del self._sessions[own[0]]
            return True
        if signed:
            unsigned = [k for k, s in self._sessions.items() if not s.signed]
            if unsigned:
                return self._reclaim(unsigned, now, idle_only=False)
        return self._reclaim(list(self._sessions), now)

    def _reclaim(self, keys: list[tuple[Requester, int]], now: float, *, idle_only: bool = True) -> bool:
        """Close the least recently used of ``keys`` (only if idle, unless ``idle_only`` is off)."""
        candidates = [k for k in keys if not idle_only or self._idle(self._sessions[k], now)]
        if not candidates:
            return False
        victim = min(candidates, key=lambda k: self._sessions[k].used)
        del self._sessions[victim]
        self.reclaimed += 1
        log.info("FTP: session %d of %d/%d reclaimed for another client", victim[1], *victim[0])
        return True

    def _idle(self, sess: Session, now: float) -> bool:
        return sess.burst_offset is None and now - sess.used > self.idle_s
