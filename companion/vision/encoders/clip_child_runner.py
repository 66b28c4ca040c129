"""Runs the CLIP torch child process (``clip_child``) for the ONNX Runtime encoder and reads its answer.

Kept apart from the child's own module, which imports torch and the CLIP loader: the encoder that calls this
must not (see clip_child.py for why the work is done in a child at all).
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import companion
from companion.errors import MerlionError

log = logging.getLogger(__name__)

CHILD_TIMEOUT_S = 900.0
"""Longest a child may take (an export of a large tower on a slow CPU takes minutes): a hung one is killed."""


def run_clip_child(request: dict, what: str, *, timeout_s: float = CHILD_TIMEOUT_S) -> dict:
    """Run the child on ``request`` and return its answer; its one-line error becomes a MerlionError.

    ``what`` says what it was for, in the log and the error ("export the image tower", "encode 2 queries").
    """
    env = dict(os.environ)  # the child imports this same checkout of the package, however the caller found it
    root = str(Path(companion.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH", "")) if p)
    start = time.monotonic()
    log.info("CLIP: starting a torch child process to %s", what)
    try:
        proc = subprocess.run([sys.executable, "-m", "companion.vision.encoders.clip_child"],
                              input=json.dumps(request), capture_output=True, text=True, env=env, check=False,
                              timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise MerlionError(f"CLIP {request.get('model')}: could not {what}: the torch child process did not "
                           f"finish within {timeout_s:.0f} s and was killed") from None
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    if proc.returncode < 0:  # killed (the OOM killer, most likely): its last stderr line is not the cause
        raise MerlionError(f"CLIP {request.get('model')}: could not {what}: the torch child process was killed "
                           f"by signal {-proc.returncode} (out of memory?)")
    if proc.returncode != 0:
        reason = lines[-1].strip() if lines else f"exit status {proc.returncode}"
        raise MerlionError(f"CLIP {request.get('model')}: could not {what}: {reason}")
    answer = json.loads(proc.stdout.strip().splitlines()[-1])
    answer["seconds"] = round(time.monotonic() - start, 2)
    log.info("CLIP: child process did %s in %.1f s (its peak RSS %.0f MB, now returned)", what,
             answer["seconds"], answer["peak_rss_mb"])
    return answer
