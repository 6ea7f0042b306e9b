"""Episode video captions: the instruction, the reading, the step, its action and the end."""

from __future__ import annotations

from vla_gr.evaluation.video import CAPTION_LINES, caption, ending, reading_line, step_line


def _row(**changes) -> dict:
    row = {
        "spec": {"instruction": "find the red chair in the kitchen"},
        "reading": {
            "category": "chair",
            "color": "red",
            "room": "kitchen",
            "anchor": None,
            "understood": True,
            "reason": None,
        },  # fmt: skip
        "actions": [[0.5, -0.25, -1.0], [0.0, 0.0, 1.0]],
        "metrics": {"success": 1.0},
        "stopped": True,
        "declared": None,
        "cause": None,
    }
    return {**row, **changes}


def test_caption_names_request_reading_step_and_action():
    row = _row()
    lines = caption(row, 1)
    assert len(lines) == CAPTION_LINES
    assert lines[0] == "“find the red chair in the kitchen”"
    assert lines[1] == "reading: category=chair color=red room=kitchen"
    assert lines[2] == "step 1/2 | v +0.50 w -0.25 stop -1.00"
    assert caption(row, 0)[2] == "step 0/2 | start"
    assert caption(row, 2)[2] == "step 2/2 | v +0.00 w +0.00 stop +1.00 | STOP: success"


def test_reading_line_without_a_reader_and_when_not_understood():
    assert reading_line(None) == "reading: - (this agent reads no request)"
    no = {"category": None, "color": None, "room": None, "anchor": None, "understood": False,
          "reason": "no object named"}  # fmt: skip
    assert reading_line(no) == "reading: nothing | not understood: no object named"


def test_ending_of_each_kind_of_episode():
    assert ending(_row()) == "STOP: success"
    failed = _row(metrics={"success": 0.0}, cause="stopped_elsewhere")
    assert ending(failed) == "STOP: failure (stopped_elsewhere)"
    timeout = _row(metrics={"success": 0.0}, stopped=False, cause="stuck")
    assert ending(timeout) == "out of steps (stuck)"
    declared = _row(metrics={"success": 0.0}, stopped=False, declared="not_found")
    assert ending(declared) == "declared not_found"
    assert step_line(declared, 2).endswith("| declared not_found")
