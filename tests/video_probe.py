"""ffprobe's view of a video file, for the tests of the videos the project writes."""

from __future__ import annotations

import subprocess


def probe(path) -> dict:
    """Codec, pixel format, size and decoded frame count of ``path``'s first video stream."""
    out = subprocess.run(
        ["ffprobe", "-v", "error", "-select_streams", "v:0", "-count_frames", "-show_entries",
         "stream=codec_name,pix_fmt,width,height,nb_read_frames", "-of", "default=nw=1", str(path)],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    return dict(line.split("=", 1) for line in out.split())
