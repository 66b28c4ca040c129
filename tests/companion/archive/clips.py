"""Short dive videos for the archive tests, cut from the survey footage with OpenCV and placed in time."""

from __future__ import annotations

import os
from pathlib import Path

import cv2


def cut_clips(video: Path, out_dir: Path, count: int, seconds: float, starts: list[float]) -> list[Path]:
    """``count`` clips of ``seconds`` each from consecutive parts of ``video`` (starting it again when it ends);
    clip i's file time says it was recorded from ``starts[i]`` (mtime = start + duration, as a recorder would)."""
    cap = cv2.VideoCapture(str(video))
    fps = cap.get(cv2.CAP_PROP_FPS) or 10.0
    per_clip = int(round(seconds * fps))
    clips = []
    for i in range(count):
        path = out_dir / f"dive{i + 1:02d}.mp4"
        writer = None
        for _ in range(per_clip):
            ok, frame = cap.read()
            if not ok:
                cap.release()
                cap = cv2.VideoCapture(str(video))
                ok, frame = cap.read()
                assert ok, f"{video}: no frames"
            if writer is None:
                h, w = frame.shape[:2]
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
            writer.write(frame)
        writer.release()
        end = starts[i] + per_clip / fps
        os.utime(path, (end, end))
        clips.append(path)
    cap.release()
    return clips
