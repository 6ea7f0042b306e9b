"""metrics.jsonl on resume: rows past the resumed step (and a line torn by a kill) go;
rollout videos read back from TensorBoard's event file."""

from __future__ import annotations

import io
import json

import numpy as np
from PIL import Image

from vla_gr.training.logger import MetricsLogger, drop_rows_after, read_metrics


def tensorboard_videos(run_dir) -> dict[str, list]:
    """``{tag: [(step, GIF as a PIL image), ...]}`` of the image summaries under
    ``run_dir/tensorboard``, read with TensorBoard's own reader."""
    from tensorboard.backend.event_processing.event_accumulator import IMAGES, EventAccumulator

    acc = EventAccumulator(str(run_dir / "tensorboard"), size_guidance={IMAGES: 0})
    acc.Reload()
    out = {}
    for tag in acc.Tags()[IMAGES]:
        for event in acc.Images(tag):
            gif = Image.open(io.BytesIO(event.encoded_image_string))
            assert gif.format == "GIF" and gif.size == (event.width, event.height)
            out.setdefault(tag, []).append((event.step, gif))
    return out


def gif_frames(gif) -> list[tuple[np.ndarray, int]]:
    """(frame (H, W, 3), duration in ms) of each frame of an animated GIF."""
    frames = []
    for k in range(gif.n_frames):
        gif.seek(k)
        frames.append((np.asarray(gif.convert("RGB")), gif.info["duration"]))
    return frames


def test_drop_rows_after_keeps_earlier_rows_and_removes_a_torn_line(tmp_path):
    path = tmp_path / "metrics.jsonl"
    rows = [{"step": s, "train/loss": 1.0 / s} for s in (1, 2, 2, 3, 4)]
    path.write_text("".join(json.dumps(r) + "\n" for r in rows) + '{"step": 5, "train/lo')
    assert drop_rows_after(path, 2) == 3  # steps 3, 4 and the torn step-5 line
    assert read_metrics(path) == rows[:3]
    assert drop_rows_after(path, 2) == 0 and read_metrics(path) == rows[:3]


def test_a_resumed_logger_appends_after_the_resumed_step(tmp_path):
    logger = MetricsLogger(tmp_path, tensorboard=False)
    for step in (1, 2, 3):
        logger.log(step, {"train/loss": float(step)})
    logger.close()
    logger = MetricsLogger(tmp_path, tensorboard=False, resume_step=2)
    logger.log(3, {"train/loss": 30.0})
    logger.close()
    rows = read_metrics(tmp_path / "metrics.jsonl")
    assert [(r["step"], r["train/loss"]) for r in rows] == [(1, 1.0), (2, 2.0), (3, 30.0)]


def test_rollout_videos_are_read_back_from_the_event_file(tmp_path):
    colours = [(200, 0, 0), (0, 200, 0), (0, 0, 200)]
    frames = [np.tile(np.array(c, np.uint8), (20, 30, 1)) for c in colours]  # (20, 30, 3) each
    logger = MetricsLogger(tmp_path)
    logger.log(5, {"val/spl": 0.5})
    logger.log_videos(5, {"val/episode_0": (frames, 4.0), "val/episode_1": (frames[:2], 2.0)})
    logger.close()
    videos = tensorboard_videos(tmp_path)
    assert set(videos) == {"val/episode_0", "val/episode_1"}
    ((step, gif),) = videos["val/episode_0"]
    assert step == 5 and gif.size == (30, 20)
    back = gif_frames(gif)
    assert [d for _, d in back] == [250, 250, 250]  # 4 frames per second
    for (frame, _), c in zip(back, colours):
        assert np.abs(frame.astype(int) - c).max() <= 8  # the colours, in order
    assert len(gif_frames(videos["val/episode_1"][0][1])) == 2
    MetricsLogger(tmp_path / "off", tensorboard=False).log_videos(1, {"x": (frames, 1.0)})
    assert not (tmp_path / "off" / "tensorboard").exists()
