"""A threaded HTTP server whose clients cannot pin it: a bounded number of handler threads, a deadline to send a
whole request, a per-read socket timeout, and a bounded request head.

``http.server.ThreadingHTTPServer`` starts one thread per connection and waits forever for a request's head and
body: 300 clients that send a Content-Length and then nothing keep 300 threads. Here at most ``max_threads``
requests are served at once (the others get a 503 at once), and a request not read in full within
``read_deadline_s`` is cut (one reaper thread for all of them), so the slots come back; one client address holds
at most ``max_per_address`` of them, so it cannot lock everyone else out. Slow senders hold slots only while nobody
else needs them: when a new connection finds no slot (or its address at its share), the oldest connection still
sending its request after ``SLOW_AFTER_S`` is cut to make room, taken from the address with the most of them (16
half-sent requests from each of two addresses held all 32 slots for the whole read deadline: 0 of 25 probes from
a third address were answered).
"""

from __future__ import annotations

import logging
import re
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

log = logging.getLogger("merlion.surface.web")

MAX_THREADS = 32
MAX_PER_ADDRESS = 16
"""Requests served at once for one client address: one address cannot take every slot and lock the page out for
everyone else (behind a reverse proxy every request comes from the proxy's address: it gets these 16)."""
SLOW_AFTER_S = 1.0
"""A connection still sending its request after this long is a slow sender: its slot goes to a newcomer that has
none (the page's own requests arrive whole in milliseconds; behind a proxy, at once)."""
CUT_WAIT_S = 1.0
"""How long the accept loop waits for the slot of a slow sender it cut (its thread ends as its read fails)."""
READ_DEADLINE_S = 10.0
"""Time to send a request's head and body (at most 16 kB + 64 kB): ample on a tether, short for a slow-loris."""
SOCKET_TIMEOUT_S = 5.0
MAX_HEAD = 16 * 1024
"""The request line and headers together."""
MAX_REQUEST_LINE = 4096
MAX_JSON_DEPTH = 32
"""How deep a request's JSON may nest (the page's actions send flat objects)."""
_JSON_SIGNIFICANT = re.compile(rb'[\[\]{}"\\]')
_BUSY = (b"HTTP/1.0 503 Service Unavailable\r\nContent-Type: text/plain\r\nContent-Length: 5\r\n"
         b"Retry-After: 1\r\nConnection: close\r\n\r\nbusy\n")


def json_too_deep(raw: bytes, limit: int = MAX_JSON_DEPTH) -> bool:
    """Whether ``raw`` nests arrays and objects deeper than ``limit``, found without parsing it: Python's JSON
    parser recurses once per level, and 30,000 ``[`` (within the 64 kB a body may have) ended the request in a
    RecursionError with no answer. One pass over the brackets, quotes and backslashes (a regular expression for
    whole strings backtracks: 64 kB of ``\\"`` took it 16 s). Brackets inside strings are text; where the body
    stops being JSON, the parser stops too, so what follows cannot make it recurse."""
    depth, in_string, escaped_at = 0, False, -1
    for match in _JSON_SIGNIFICANT.finditer(raw):
        at, char = match.start(), raw[match.start()]
        if at == escaped_at:
            continue
        if in_string:
            if char == 0x5C:  # backslash: the next byte is escaped
                escaped_at = at + 1
            elif char == 0x22:
                in_string = False
        elif char == 0x22:
            in_string = True
        elif char in b"[{":
            depth += 1
            if depth > limit:
                return True
        elif char in b"]}":
            depth -= 1
    return False


class HeadTooLarge(Exception):
    """The request's head went past ``MAX_HEAD``."""


class BoundedReader:
    """The connection's input with a byte budget: the head may not exceed it (``allow`` then sets the body's)."""

    def __init__(self, raw, budget: int) -> None:
        self._raw = raw
        self._left = budget

    def allow(self, budget: int) -> None:
        self._left = budget

    def readline(self, limit: int = -1) -> bytes:
        want = self._left + 1 if limit < 0 else min(limit, self._left + 1)
        line = self._raw.readline(want)
        self._left -= len(line)
        if self._left < 0:
            raise HeadTooLarge()
        return line

    def read(self, n: int = -1) -> bytes:
        data = self._raw.read(min(n, self._left) if n >= 0 else self._left)
        self._left -= len(data)
        return data

    def __getattr__(self, name: str):
        return getattr(self._raw, name)


class BoundedHandler(BaseHTTPRequestHandler):
    """A request handler whose head is bounded; subclasses call ``request_read`` once the body is in."""

    timeout = SOCKET_TIMEOUT_S

    def setup(self) -> None:
        super().setup()
        self.rfile = BoundedReader(self.rfile, MAX_HEAD)

    def handle_one_request(self) -> None:
        try:
            super().handle_one_request()
        except HeadTooLarge:
            self.requestline, self.request_version, self.command = "", "HTTP/1.0", None
            self.send_error(431, "request head too large")
            self.close_connection = True
        except (TimeoutError, ConnectionError, OSError) as err:  # a slow or vanished client: nothing to answer
            log.debug("web: %s: %s", self.client_address[0], err)
            self.close_connection = True

    def parse_request(self) -> bool:
        if len(self.raw_requestline) > MAX_REQUEST_LINE:
            self.requestline, self.request_version, self.command = "", "HTTP/1.0", None
            self.send_error(414, "request line too long")
            return False
        return super().parse_request()

    def request_read(self) -> None:
        """The whole request is in: the read deadline no longer applies (an answer may take long, e.g. an FTP
        fetch over the link)."""
        self.server.unwatch(self.connection)


class BoundedHTTPServer(ThreadingHTTPServer):
    """``ThreadingHTTPServer`` with at most ``max_threads`` handlers and a deadline to read each request."""

    daemon_threads = True
    request_queue_size = 128
    """The listen backlog: socketserver's 5 made a burst of clients (a page's parallel fetches, or a flood) wait
    for SYN retries of a second and more before the accept loop could even answer them busy."""

    def __init__(self, address, handler: type[BoundedHandler], *, max_threads: int = MAX_THREADS,
                 max_per_address: int = MAX_PER_ADDRESS, read_deadline_s: float = READ_DEADLINE_S) -> None:
        self._closed = threading.Event()  # before the bind: a failed bind calls server_close, which sets it
        super().__init__(address, handler)
        self.max_threads = max_threads
        self.max_per_address = max_per_address
        self._by_address: dict[str, int] = {}
        self.read_deadline_s = read_deadline_s
        self.refused_busy = 0
        self.cut_slow = 0
        self._slots = threading.BoundedSemaphore(max_threads)
        self._serving = 0
        self._deadlines: dict[socket.socket, float] = {}
        self._sending: dict[socket.socket, tuple[float, str]] = {}
        """Connections still sending their request: when accepted, and from which address."""
        self._watch_lock = threading.Lock()
        self._reaper = threading.Thread(target=self._reap, name="surface-web-reaper", daemon=True)
        self._reaper.start()

    def process_request(self, request, client_address) -> None:
        """On the accept thread (the only one that takes slots): a slot for this request, or a 503 at once."""
        address = client_address[0]
        with self._watch_lock:
            mine = self._by_address.get(address, 0)
        room = mine < self.max_per_address or self._cut_slow_sender(address)
        if room and not self._slots.acquire(blocking=False):
            room = self._cut_slow_sender(None) and self._slots.acquire(timeout=CUT_WAIT_S)
        if not room:
            self.refused_busy += 1
            try:
                request.settimeout(1.0)
                request.sendall(_BUSY)
            except OSError:
                pass
            self.shutdown_request(request)
            return
        with self._watch_lock:
            now = time.monotonic()
            self._deadlines[request] = now + self.read_deadline_s
            self._sending[request] = (now, address)
            self._serving += 1
            self._by_address[address] = self._by_address.get(address, 0) + 1
        threading.Thread(target=self._serve_one, args=(request, client_address), daemon=True).start()

    def _serve_one(self, request, client_address) -> None:
        try:
            self.finish_request(request, client_address)
        except Exception as err:  # never a traceback on stderr: one line in the log
            log.warning("web: request from %s failed: %s", client_address[0], err)
        finally:
            self.unwatch(request)
            self.shutdown_request(request)
            with self._watch_lock:
                self._serving -= 1
                left = self._by_address.pop(client_address[0]) - 1
                if left:
                    self._by_address[client_address[0]] = left
            self._slots.release()

    def unwatch(self, request) -> None:
        with self._watch_lock:
            self._deadlines.pop(request, None)
            self._sending.pop(request, None)

    def _cut_slow_sender(self, address: str | None) -> bool:
        """Cut the oldest connection still sending after ``SLOW_AFTER_S``, of ``address`` (None: of the address
        with the most such connections); False when there is none."""
        now = time.monotonic()
        with self._watch_lock:
            slow = [(at, addr, s) for s, (at, addr) in self._sending.items()
                    if now - at >= SLOW_AFTER_S and (address is None or addr == address)]
            if not slow:
                return False
            counts: dict[str, int] = {}
            for _at, addr, _s in slow:
                counts[addr] = counts.get(addr, 0) + 1
            worst = max(counts, key=counts.get)
            _at, _addr, victim = min((entry for entry in slow if entry[1] == worst), key=lambda entry: entry[0])
            self._deadlines.pop(victim, None)
            self._sending.pop(victim, None)
        self.cut_slow += 1
        try:
            victim.shutdown(socket.SHUT_RDWR)  # its handler's blocked read returns; its thread ends, its slot frees
        except OSError:
            pass
        return True

    def slow_senders(self) -> int:
        """Connections still sending their request after ``SLOW_AFTER_S`` (the ones a newcomer may cut)."""
        now = time.monotonic()
        with self._watch_lock:
            return sum(1 for at, _addr in self._sending.values() if now - at >= SLOW_AFTER_S)

    def busy(self) -> int:
        """Requests being served now."""
        with self._watch_lock:
            return self._serving

    def _reap(self) -> None:
        while not self._closed.wait(0.25):
            now = time.monotonic()
            with self._watch_lock:
                late = [s for s, deadline in self._deadlines.items() if deadline <= now]
                for s in late:
                    del self._deadlines[s]
                    self._sending.pop(s, None)
            for s in late:
                self.cut_slow += 1
                try:
                    s.shutdown(socket.SHUT_RDWR)  # the handler's blocked read returns; its thread ends
                except OSError:
                    pass

    def handle_error(self, request, client_address) -> None:
        log.debug("web: error serving %s", client_address[0])

    def server_close(self) -> None:
        self._closed.set()
        super().server_close()
