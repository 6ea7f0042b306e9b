"""``report.html``: the report's tables, charts and episode videos, opened in headless Chromium
(a screenshot that is not blank, every video loaded); the videos hold every replayed step."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from tests.chromium import CHROMIUM, Chromium
from tests.video_probe import probe
from vla_gr.configs import load_config
from vla_gr.evaluate import evaluate, expand_aliases
from vla_gr.evaluation.report import html_page
from vla_gr.evaluation.video import END_HOLD_SECONDS

PANEL, STRIDE = 64, 3
needs_ffmpeg = pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="no ffmpeg on PATH")


def test_html_page_has_tables_pictures_players_and_shows_written_html_as_text():
    text = (
        "# Evaluation: a\n\n| name | x |\n|---|---|\n| a | 1 |\n\n![chart](c.png)\n\n"
        "find the <script>alert(1)</script> chair & more\n\n[video](episode_0001_success.mp4)\n"
    )
    page = html_page(text, "Evaluation: <a>")
    assert page.startswith("<!DOCTYPE html>") and "<title>Evaluation: &lt;a&gt;</title>" in page
    assert "<table>" in page and "<td>a</td>" in page and '<img alt="chart" src="c.png"' in page
    assert '<video src="episode_0001_success.mp4" controls' in page and "<a href" not in page
    assert "<script>" not in page and "&lt;script&gt;alert(1)&lt;/script&gt; chair &amp;" in page


def test_without_ffmpeg_the_report_has_pictures_and_says_there_are_no_videos(
    tmp_path, monkeypatch, caplog
):
    from vla_gr.evaluation import harness

    monkeypatch.setattr(harness.shutil, "which", lambda name: None)
    out = tmp_path / "expert"
    args = [f"output_dir={out}", "agent=expert", "num_episodes=1", "eval.progress=false"]
    evaluate(load_config("config_debug", expand_aliases(args))[1])
    assert "no ffmpeg on PATH" in caplog.text
    assert not list(out.glob("*.mp4")) and len(list(out.glob("*_topdown.png"))) == 1
    assert "(no video: no ffmpeg)" in (out / "report.md").read_text()
    assert "<video" not in (out / "report.html").read_text()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """An expert evaluation of two episodes with a video of every episode."""
    out = tmp_path_factory.mktemp("report") / "expert"
    args = [
        f"output_dir={out}", "agent=expert", "num_episodes=2", "eval.progress=false",
        "eval.video_all=true", f"eval.video_panel={PANEL}", f"eval.video_stride={STRIDE}",
        "env.max_episode_steps=120",
    ]  # fmt: skip
    _, cfg = load_config("config_debug", expand_aliases(args))
    evaluate(cfg)
    return out, cfg


@needs_ffmpeg
def test_every_episode_has_a_video_of_every_replayed_step(run):
    out, cfg = run
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    videos = sorted(out.glob("*.mp4"))
    assert len(videos) == len(rows) == 2  # video_all: every episode, not only the picked ones
    md = (out / "report.md").read_text()
    page = (out / "report.html").read_text()
    fps = cfg.env.control_hz / STRIDE
    for row, video in zip(rows, videos):
        assert video.name.startswith(f"episode_{row['episode_index']:04d}_")
        assert f"[video]({video.name})" in md and f'<video src="{video.name}"' in page
        assert f"![top-down]({video.stem}_topdown.png)" in md
        # steps 0, STRIDE, 2 STRIDE, ..., the last one; then the last frame held
        replayed = 1 + math.ceil(len(row["actions"]) / STRIDE)
        assert int(probe(video)["nb_read_frames"]) == replayed + round(END_HOLD_SECONDS * fps) - 1


@needs_ffmpeg
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (make setup installs it)")
def test_report_html_opens_in_chromium_with_every_video_loaded(run, tmp_path):
    out, _ = run
    videos = "Array.from(document.querySelectorAll('video'))"
    loaded = f"{videos}.every(v => v.readyState >= 2) && {videos}.map(v => v.readyState)"
    with Chromium(tmp_path / "profile") as browser:
        page = browser.open((out / "report.html").as_uri())
        states = browser.wait_for(page, f"document.readyState === 'complete' && ({loaded})")
        sizes = browser.evaluate(page, f"{videos}.map(v => [v.videoWidth, v.videoHeight])")
        errors = browser.evaluate(page, f"{videos}.map(v => v.error && v.error.code)")
        charts = browser.evaluate(
            page, "Array.from(document.images).map(i => i.complete && i.naturalWidth)"
        )
        shot = browser.screenshot(page)
    assert errors == [None, None]
    assert states and len(states) == 2 and min(states) >= 2, states  # HAVE_CURRENT_DATA or more
    assert all(w == 3 * PANEL and h > PANEL for w, h in sizes)  # RGB | depth | map, caption
    assert len(charts) == 3 and all(charts)  # breakdowns.png and two top-down PNGs
    colours = np.unique(shot.reshape(-1, 3), axis=0)
    assert shot.std() > 20 and len(colours) > 50  # a rendered page, not a blank one
