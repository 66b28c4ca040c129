"""``merlion demo``: the whole system on one machine, on loopback, in one command.

Three programs talk MAVLink through a small UDP hub (standing in for the vehicle's router): the simulated ArduSub
(``merlion sim-vehicle``, a subprocess), the companion (in this process, on the embedded defaults: the generated
murky dive and the packaged encoder) and the surface tool (``merlion surface``, a subprocess that keeps a
gallery). After ``duration`` seconds or Ctrl-C everything stops, and DIR holds the surface gallery
(DIR/surface/), the on-board store (DIR/store/) and report.json; a short report is printed.

The demo uses the configured tau_ss (0.5 by default) on the generated dive as on real video. The packaged
encoder answers "fish" after a dive's first frame with its scene head (``encoders/heads/fish-scene.json``: what
a frame adds to the dive so far), which sets the drawn fish apart as it does filmed ones. Measured on every frame
of two cycles of the 8 s dive scored as one dive: at 0.5, none of the 240 descent, sand and sea-grass frames pass,
against all 80 reef-fish frames (median 0.998) and 61 of 80 large-fish frames. (Until the live companion
used the scene head, the drawn fish scored 0.01-0.34 on the pooled head and the demo lowered tau_ss to 0.02.)
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2

from companion.atomic_write import atomic_write
from companion.config import Config, SourceConfig, build_config
from companion.errors import MerlionError, UsageError
from companion.live import die_with_parent
from companion.live.companion import LiveCompanion, LiveOptions
from companion.live.udp_hub import UdpHub
from companion.sources.factory import check_file_source
from companion.storage.store import Store
from companion.storage.store_lock import StoreLock, holding
from companion.vision.contact_sheet import Tile, contact_sheet

log = logging.getLogger(__name__)

DEMO_SOURCE = "synthetic://dive?seconds=8"
SURVEY_HINT = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "survey" / "survey_480x270.mp4"


@dataclass
class DemoOptions:
    out: Path
    duration: float = 60.0
    source: str | None = None
    tau_ss: float | None = None
    encoder: str = "auto"
    budget_bytes_per_s: int = 4000
    """The demo's loopback link is faster than an acoustic modem, slower than a tether: thumbnails take seconds."""
    fps: float = 5.0
    realtime: bool = True
    quiet: bool = False
    web_port: int = 0
    """The surface tool's live page (0: a free port); its URL is printed at the start."""
    signing_key: str | None = None
    """MAVLink 2 signing key file shared by the simulator, the companion and the surface tool."""
    resume: bool = False
    """Continue the store and gallery of an earlier run in ``out``; by default that run is moved aside."""


def check_source(opts: DemoOptions) -> None:
    """A file or folder that cannot be read (missing, damaged, no images) stops the demo before it starts."""
    if opts.source:
        check_file_source(SourceConfig(uri=opts.source, fps=opts.fps), "--source")


def demo_config(opts: DemoOptions, *, hub_url: str) -> Config:
    check_source(opts)
    source = opts.source or DEMO_SOURCE
    data: dict[str, Any] = {
        "source": {"uri": source, "fps": opts.fps, "realtime": opts.realtime, "loop": bool(opts.source)},
        "encoder": {"name": opts.encoder},
        "mavlink": {"connection": hub_url, "component_id": 100, "signing_key_file": opts.signing_key},
        "surface": {"budget_bytes_per_s": opts.budget_bytes_per_s},
        "store": {"dir": str(opts.out / "store")},
        "health": {"stall_after_s": 60.0},
    }
    if opts.tau_ss is not None:
        data["queries"] = {"tau_ss": opts.tau_ss}
    return build_config(data, origin="demo")


def _merlion(*args: str) -> list[str]:
    return [sys.executable, "-m", "companion", *args]


def _spawn(args: list[str], log_path: Path) -> subprocess.Popen:
    """A child in its own session (a terminal's Ctrl-C reaches only the demo, which stops the children in order)
    that still dies with the demo when the demo is killed outright (``die_with_parent``)."""
    # the child gets its own copy of the descriptor; the demo's copy is closed at once instead of leaking
    with open(log_path, "w", encoding="utf-8") as fh:
        return subprocess.Popen(die_with_parent.command(args), stdout=fh, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _end(proc: subprocess.Popen | None, timeout: float = 15.0) -> int | None:
    if proc is None:
        return None
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


def _page_url(proc: subprocess.Popen, log_path: Path, timeout: float = 30.0) -> str | None:
    """The live page's URL, from the line the surface tool prints once it listens (None if it never does)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        try:
            match = re.search(r"live page at (\S+)", log_path.read_text(encoding="utf-8", errors="replace"))
        except OSError:
            match = None
        if match:
            return match.group(1)
        time.sleep(0.1)
    return None


def _child_failed(name: str, code: int, log_path: Path) -> MerlionError:
    """A child that stopped at start, as the demo's one error line: the child's own error line (what was wrong, e.g.
    a port in use), with its exit code (2: bad input)."""
    try:
        said = [line for line in log_path.read_text(encoding="utf-8", errors="replace").splitlines()
                if line.startswith("merlion: error: ")]
    except OSError:
        said = []
    why = said[-1].removeprefix("merlion: error: ") if said else f"exited with code {code}; see {log_path}"
    return MerlionError(f"{name}: {why}", exit_code=2 if code == 2 else 1)


def write_contact_sheet(store: Store, path: Path) -> Path | None:
    """The summary as one image, each frame with its time, score and depth drawn on it (None: cannot write)."""
    tiles = []
    for index in store.summary:
        frame = store.frame(index)
        if frame is None:
            continue
        depth = frame.pose.depth_m if frame.pose is not None and not frame.pose.stale else None
        tiles.append(Tile(frame.image, frame.time_s, frame.score, depth))
    sheet = contact_sheet(tiles, title=f"MERLION summary, dive {store.dive}: {len(tiles)} frames")
    ok, buf = cv2.imencode(".jpg", sheet, [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        return None
    try:
        atomic_write(path, buf.tobytes())
    except OSError as err:
        log.warning("%s: cannot write the contact sheet (%s)", path, err.strerror or err)
        return None
    return path


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _gallery_counts(surface_dir: Path) -> tuple[int, int, int]:
    """(captures announced, in the summary now, with a thumbnail) from the surface tool's gallery.json."""
    path = surface_dir / "gallery.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return 0, 0, 0
    caps = doc.get("captures", doc if isinstance(doc, list) else [])
    if isinstance(caps, dict):
        caps = list(caps.values())
    held = [c for c in caps if c.get("in_summary")]
    thumbs = [c for c in caps if c.get("thumbnail")]
    return len(caps), len(held), len(thumbs)


def _surface_settled(surface_dir: Path, summary: list[int], timeout: float) -> bool:
    """Wait (at most ``timeout``) until the surface gallery holds exactly ``summary``, each with a thumbnail."""
    end = time.monotonic() + timeout
    while True:
        try:
            doc = json.loads((surface_dir / "gallery.json").read_text(encoding="utf-8"))
            held = {c["image_index"]: c for c in doc.get("captures", []) if c.get("in_summary")}
            if set(held) == set(summary) and all(c.get("thumbnail") for c in held.values()):
                return True
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass
        if time.monotonic() >= end:
            return False
        time.sleep(0.1)


def run_demo(opts: DemoOptions, stop: threading.Event | None = None, *,
             store_lock: StoreLock | None = None) -> dict[str, Any]:
    """Run the demo; returns the report (also written to DIR/report.json). ``store_lock``: DIR/store's, held by
    the caller until the report is written (None: the companion takes it when it starts)."""
    stop = stop or threading.Event()
    check_source(opts)
    out = opts.out
    logs = out / "logs"
    try:
        for folder in (out / "surface", out / "store", logs):
            folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise MerlionError(f"--out {out}: cannot create {err.filename or out} ({err.strerror or err})") from None
    surface_port = _free_udp_port()
    hub = UdpHub(outputs=[("127.0.0.1", surface_port)]).start()
    cfg = demo_config(opts, hub_url=hub.url)
    sim = surface = None
    companion: LiveCompanion | None = None
    started = time.monotonic()
    try:
        signing = ["--signing-key", opts.signing_key] if opts.signing_key else []
        sim = _spawn(_merlion("sim-vehicle", "--connect", hub.url, *signing), logs / "sim-vehicle.log")
        surface = _spawn(_merlion("surface", "--connect", f"udpin:127.0.0.1:{surface_port}", "--out",
                                  str(out / "surface"), "--companion", "1:100", "--web", str(opts.web_port),
                                  "--web-host", "127.0.0.1", *signing), logs / "surface.log")
        page = _page_url(surface, logs / "surface.log")
        if page:
            _say(opts, f"merlion demo: surface page at {page} (live while the demo runs)")
        elif surface.poll() is not None:  # it stopped at start (its page's port taken meanwhile): so does the demo
            raise _child_failed("surface", surface.returncode, logs / "surface.log")
        else:
            log.warning("the surface tool did not start its page; see %s", logs / "surface.log")
        companion = LiveCompanion(cfg, LiveOptions(store_lock=store_lock))
        companion.start()
        _say(opts, f"merlion demo: companion running on {cfg.source.uri} with {companion.encoder.name}; "
                   f"simulated ArduSub and surface tool on loopback; {opts.duration:.0f} s (Ctrl-C ends it early)")
        deadline = time.monotonic() + opts.duration
        while not stop.is_set() and time.monotonic() < deadline:  # a progress line every 10 s
            companion.run(duration=min(10.0, max(0.0, deadline - time.monotonic())), stop=stop)
            _say(opts, f"  {opts.duration - max(0.0, deadline - time.monotonic()):4.0f} s  {companion.status_line()}")
        for proc, name in ((sim, "sim-vehicle"), (surface, "surface")):
            if proc.poll() is not None:
                log.warning("%s exited early (code %s); see %s", name, proc.returncode, logs / f"{name}.log")
        companion.stop_pipeline()
        companion.drain(timeout=20.0)
        held = companion.store.summary if companion.store is not None else []
        _surface_settled(out / "surface", held, timeout=10.0)  # the last trims and thumbnails still on the way
    finally:
        if companion is not None:
            companion.stop()
        surface_rc = _end(surface)
        _end(sim)
        hub.stop()
    report = companion.report()
    sheet = write_contact_sheet(companion.store, out / "contact_sheet.jpg") if companion.store is not None else None
    announced, held, thumbs = _gallery_counts(out / "surface")
    report.update({
        "duration_s": round(time.monotonic() - started, 1), "source": cfg.source.uri, "tau_ss": cfg.queries.tau_ss,
        "surface_captures": announced, "surface_summary": held, "thumbnails_delivered": thumbs,
        "surface_exit": surface_rc, "out": str(out), "web_url": page,
        "offline_page": str(out / "surface" / "index.html"), "contact_sheet": str(sheet) if sheet else None,
    })
    (out / "report.json").write_text(json.dumps(report, indent=1, default=str))
    return report


def _say(opts: DemoOptions, text: str) -> None:
    if not opts.quiet:
        print(text, flush=True)


def format_report(report: dict[str, Any], *, survey_hint: bool) -> str:
    lines = [
        "merlion demo: done",
        f"  source             {report['source']} (tau_ss {report['tau_ss']:.2f}, encoder {report['encoder']})",
        f"  frames seen        {report['frames_seen']} (scored {report['frames_scored']}, dropped while the "
        f"encoder was busy {report['frames_dropped']})",
        f"  frames passed      {report['frames_passed']} (semantic score above tau_ss)",
        f"  summary            {len(report['summary'])} frames now, image indices {report['summary']} "
        f"({report['summary_added']} added, {report['summary_removed']} trimmed)",
        f"  thumbnails         {report['thumbnails_delivered']} delivered to the surface "
        f"({report['surface_summary']} in its summary)",
        f"  bytes sent         {report['bytes_sent']} on the MAVLink link",
        f"  on-board store     {report['out']}/store",
        f"  surface gallery    {report['out']}/surface (gallery.json, log.csv, thumbnails)",
        f"  surface page       {report['offline_page']} (opens from disk)",
        f"  report             {report['out']}/report.json; process logs in {report['out']}/logs",
    ]
    if survey_hint:
        lines.append(f"  real video         merlion demo --source {SURVEY_HINT}")
    if report.get("contact_sheet"):
        lines.append(f"  contact sheet      {report['contact_sheet']}")
    return "\n".join(lines)


def set_aside_previous_run(out: Path) -> Path | None:
    """A demo starts fresh: an earlier run's output in ``out`` is renamed to a sibling ``<out>.previous-<time>``
    (never deleted); returns where it went, or None when ``out`` held nothing."""
    if not out.is_dir() or not any(out.iterdir()):
        return None
    stamp = time.strftime("%Y%m%dT%H%M%S")
    target = out.with_name(f"{out.name}.previous-{stamp}")
    n = 1
    while target.exists():
        n += 1
        target = out.with_name(f"{out.name}.previous-{stamp}-{n}")
    try:
        out.rename(target)
    except OSError as err:
        raise MerlionError(f"--out {out}: holds an earlier run that cannot be moved aside ({err.strerror or err}); "
                           f"pass --resume to continue it or choose another --out") from None
    return target


@contextlib.contextmanager
def _one_start_at_a_time(out: Path) -> Iterator[None]:
    """Demos starting beside each other (one parent folder) take turns to check, move aside and lock ``out``
    (a few milliseconds): a ``flock`` on the parent folder, which creates no file. Without it, two demos started
    together both passed the check before either held the store: one moved the other's fresh output aside, and
    both surface tools wrote one gallery until the second companion was refused."""
    parent = out.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(parent, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as err:
        raise MerlionError(f"--out {out}: cannot create {err.filename or parent} ({err.strerror or err})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def claim_out(opts: DemoOptions) -> StoreLock:
    """Move an earlier run aside (or keep it, with ``resume``) and take DIR/store's lock, all before anything is
    started or written: a run or demo holding that store stops this one (StoreInUse, exit 2) with nothing moved."""
    out = opts.out
    with _one_start_at_a_time(out):
        with holding(out / "store"):  # no run may take the earlier store while it is being moved
            if opts.resume:
                if out.is_dir() and any(out.iterdir()):
                    _say(opts, f"merlion demo: resuming the earlier run in {out} (its store and gallery go on)")
            else:
                moved = set_aside_previous_run(out)
                if moved is not None:
                    _say(opts, f"merlion demo: starting fresh; the earlier run in {out} was moved to {moved}")
        try:
            (out / "store").mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise MerlionError(f"--out {out}: cannot create {err.filename or out} ({err.strerror or err})") from None
        lock = StoreLock(out / "store")
        lock.acquire()
    return lock


def main(opts: DemoOptions) -> int:
    if not 0 <= opts.web_port <= 65535:
        raise UsageError(f"--web {opts.web_port}: not a port (0-65535; 0 picks a free one)")
    if opts.out.exists() and not opts.out.is_dir():
        raise UsageError(f"--out {opts.out}: exists and is not a folder")
    check_source(opts)  # a bad --source moves nothing aside
    store_lock = claim_out(opts)  # held until the report is written, so no demo moves this one's output away
    try:
        return _run(opts, store_lock)
    finally:
        store_lock.release()


def _run(opts: DemoOptions, store_lock: StoreLock) -> int:
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():  # Ctrl-C ends the demo early, with its report
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        report = run_demo(opts, stop, store_lock=store_lock)
    except OSError as err:
        raise MerlionError(f"demo: {err}") from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(format_report(report, survey_hint=opts.source is None and SURVEY_HINT.is_file()), flush=True)
    return 0


if os.name != "posix":  # pragma: no cover - the demo relies on POSIX signals for its subprocesses
    raise ImportError("merlion demo needs a POSIX system")
