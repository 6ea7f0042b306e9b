"""Episode videos: a finished episode replayed from its recorded actions, one frame per
``stride`` steps: RGB | depth | top-down map (path so far, goal, metre scale) over a caption
of the instruction, the agent's reading, the step and its action (v, ω, stop).

Frames are made after an episode, never in its loop: the env is deterministic given the
episode (noise included), so replaying a row's ``actions`` retraces it. ``vla-gr eval``'s
report encodes them as MP4 and training's closed-loop validation logs them to TensorBoard.
"""

from __future__ import annotations

import logging

import numpy as np

from vla_gr.evaluation.summary import fields_text

log = logging.getLogger(__name__)

#: Caption lines under every frame: the instruction, the reading, the step and its action.
CAPTION_LINES = 3
#: Seconds the last frame stays on screen, so that a viewer sees how the episode ended.
END_HOLD_SECONDS = 1.0


def reading_line(reading: dict | None) -> str:
    """How the agent read the request (a row's ``reading``), as one caption line."""
    if reading is None:
        return "reading: - (this agent reads no request)"
    line = f"reading: {fields_text(reading)}"
    if not reading.get("understood", True):
        line += f" | not understood: {reading.get('reason') or 'no reason given'}"
    return line


def ending(row: dict) -> str:
    """How ``row``'s episode ended: its STOP and outcome, a declaration or the budget."""
    if row.get("declared"):
        return f"declared {row['declared']}"
    if row["metrics"]["success"]:
        return "STOP: success"
    if row["stopped"]:
        return f"STOP: failure ({row['cause']})"
    return f"out of steps ({row['cause']})"


def step_line(row: dict, step: int) -> str:
    """'step 12/87 | v +0.50 w -0.20 stop -1.00' for the frame after ``step`` actions of
    ``row`` (its last frame also says how the episode ended)."""
    actions = row["actions"]
    line = f"step {step}/{len(actions)}"
    if step == 0:
        line += " | start"
    else:
        v, w, stop = actions[step - 1]
        line += f" | v {v:+.2f} w {w:+.2f} stop {stop:+.2f}"
    if step == len(actions):
        line += f" | {ending(row)}"
    return line


def caption(row: dict, step: int) -> list[str]:
    """The :data:`CAPTION_LINES` lines under ``row``'s frame after ``step`` actions."""
    return [
        f"“{row['spec']['instruction']}”",
        reading_line(row.get("reading")),
        step_line(row, step),
    ]


def reset_to(env, row: dict) -> None:
    """Reset ``env`` to the episode of ``row`` (as the run that wrote the row did)."""
    env.reset(options={"episode": int(row["episode_index"])})


def replay_frames(env, row: dict, panel: int, stride: int) -> list[np.ndarray]:
    """Replay ``row``'s actions in ``env`` (reset to its episode) and return the frames of
    steps 0, ``stride``, 2 ``stride``, ... and the last, each (panel + caption, 3 * panel, 3)
    uint8. ``env`` is left at the episode's end; a replay that ends elsewhere than the row
    says is logged as a warning."""
    from vla_gr.envs.visualize import EpisodeRecorder

    if stride < 1:
        raise ValueError(f"stride={stride} must be >= 1")
    reset_to(env, row)
    u = env.unwrapped
    start = np.asarray(u.start_pose_world, dtype=np.float64)  # (3,)
    recorder = EpisodeRecorder(u.house, u.goal_id, start, panel, float(u.max_depth), CAPTION_LINES)
    recorder.add(*u.render_rgbd(panel), u.robot_pose_world(), caption(row, 0))
    actions = row["actions"]
    for t, action in enumerate(actions, start=1):
        if t == len(actions) and row.get("declared"):
            u.declare(row["declared"])  # how the episode ended: no motion, no STOP
        else:
            env.step(np.asarray(action, dtype=np.float32))
        if t % stride == 0 or t == len(actions):
            recorder.add(*u.render_rgbd(panel), u.robot_pose_world(), caption(row, t))
    if not np.allclose(u.robot_pose_world()[:2], row["trace"]["xy"][-1], atol=1e-3):
        log.warning("episode %d: the replay ended elsewhere", row["episode_index"])
    return recorder.frames


def episode_clip(env, row: dict, panel: int, stride: int) -> tuple[list[np.ndarray], float]:
    """(frames, frames per second) of ``row``'s video: :func:`replay_frames` played in real
    time (the env's control rate over ``stride``), the last frame held
    :data:`END_HOLD_SECONDS`."""
    frames = replay_frames(env, row, panel, stride)
    fps = float(env.unwrapped.control_hz) / stride
    hold = max(0, round(END_HOLD_SECONDS * fps) - 1)
    return frames + [frames[-1]] * hold, fps
