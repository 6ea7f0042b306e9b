"""``vla-gr read TEXT [checkpoint=PATH]``: the reading printed, exit codes, bad input in one
line; the policy is a tiny fake patched in for ``load_policy`` (no checkpoint is loaded)."""

from __future__ import annotations

import subprocess
import sys

import pytest

import vla_gr.policy
from vla_gr.agent.reading import Reading
from vla_gr.checkpoint import CheckpointError
from vla_gr.cli import main
from vla_gr.errors import UserError
from vla_gr.read_cli import DEFAULT_CHECKPOINT, format_reading

RED_CHAIR = Reading(
    request="take me to the red chair by the tv",
    category="chair",
    color="red",
    anchor="tv_monitor",
    confidence={"category": 0.981, "color": 0.99, "room": 0.97, "anchor": 0.95},
    understood=True,
)
PIANO = Reading(
    request="find the piano",
    confidence={"category": 0.2},
    unknown=("piano",),
    reason="no goal I can find in 'piano'; I can find a chair, sofa, bed, toilet, tv or plant",
)


class FakeReader:
    """A policy with ``read``: each request's reading from a table; records what it read."""

    def __init__(self) -> None:
        self.requests: list[str] = []

    def read(self, request: str) -> Reading:
        self.requests.append(request)
        if len(request) > 50:
            raise UserError("request of 51 characters is longer than the 50 read")
        return RED_CHAIR if "chair" in request else PIANO


class NoReader:
    """A policy class without ``read`` (as the end-to-end agent is)."""


@pytest.fixture
def loads(monkeypatch):
    """Patches ``vla_gr.policy.load_policy``; ``loads.policy`` is what it returns (or raises),
    ``loads.paths`` the checkpoints asked for."""

    class Loads:
        policy: object = FakeReader()
        paths: list[str] = []

    def load_policy(path, *args, **kwargs):
        Loads.paths.append(str(path))
        if isinstance(Loads.policy, Exception):
            raise Loads.policy
        return Loads.policy

    Loads.paths = []
    monkeypatch.setattr(vla_gr.policy, "load_policy", load_policy)
    return Loads


def test_an_understood_request_prints_its_reading_and_exits_0(loads, capsys):
    assert main(["read", "the red chair next to the TV", "checkpoint=/runs/a/best"]) == 0
    assert loads.paths == ["/runs/a/best"]
    assert loads.policy.requests == ["the red chair next to the TV"]
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == [
        "request", "understood", "category", "color", "room", "anchor", "unknown", "reason",
    ]  # fmt: skip
    assert lines[0].split(None, 1)[1] == "the red chair next to the TV"
    assert lines[1].split() == ["understood", "yes"]
    assert lines[2].split() == ["category", "chair", "0.98"]
    assert lines[4].split() == ["room", "-", "0.97"]  # not named, sure of it
    assert lines[5].split() == ["anchor", "tv_monitor", "0.95"]
    assert lines[6].split() == ["unknown", "-"] and lines[7].split() == ["reason", "-"]
    starts = {line.index(line.split()[1], len(line.split()[0])) for line in lines}
    assert len(starts) == 1  # values in one column
    sure = {line.rindex(line.split()[-1]) for line in lines[2:6]}
    assert len(sure) == 1  # confidences in one column


def test_a_request_not_understood_prints_why_and_exits_3(loads, capsys):
    assert main(["read", "I\u2019m looking for the piano \U0001f3b9"]) == 3
    assert loads.paths == [DEFAULT_CHECKPOINT]  # the shipped checkpoint by default
    assert loads.policy.requests == ["I\u2019m looking for the piano \U0001f3b9"]  # as typed
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split(None, 1)[1] == "I'm looking for the piano"  # printed folded
    assert lines[1].split() == ["understood", "no"]
    assert lines[2].split() == ["category", "-", "0.20"]
    assert lines[3].split() == ["color", "-", "-"]  # no confidence reported
    assert lines[6].split() == ["unknown", "piano"]
    assert lines[7].split(None, 1) == ["reason", PIANO.reason]


def test_format_reading_marks_a_blank_request_and_lists_unknown_words():
    reading = Reading("qwerty zxcv", unknown=("qwerty", "zxcv"), reason="no goal named")
    lines = format_reading("\t  ", reading)
    assert lines[0].split() == ["request", "(blank)"]
    assert lines[6].split(None, 1) == ["unknown", "qwerty, zxcv"]


@pytest.mark.parametrize(
    "policy, message",
    [
        (NoReader(), "holds a NoReader, which reads no requests"),
        (CheckpointError("checkpoint /gone does not exist"), "checkpoint /gone does not exist"),
    ],
)
def test_an_agent_that_cannot_read_is_one_line_and_exit_2(loads, capsys, policy, message):
    loads.policy = policy
    assert main(["read", "find the chair", "checkpoint=/gone"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err.strip()
    assert err.startswith("vla-gr read: error:") and message in err
    assert len(err.splitlines()) == 1 and "Traceback" not in err


def test_a_request_the_reader_refuses_is_one_line_and_exit_2(loads, capsys):
    assert main(["read", "the chair " * 6]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "vla-gr read: error: request of 51 characters is longer than the 50 read"


def test_a_request_longer_than_any_reader_reads_is_refused_before_any_load(loads, capsys):
    from vla_gr.agent.reading import MAX_REQUEST_CHARS

    assert main(["read", "chair " * 100]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"vla-gr read: error: request of 599 characters is longer than the {MAX_REQUEST_CHARS} "
        "read; say it in fewer words"
    )
    assert loads.paths == []  # no agent loaded: no loading output before the line


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["find", "the", "chair"],
            "unknown argument 'the'; vla-gr read takes TEXT and checkpoint=",
        ),
        (["find the chair", "device=cpu"], "unknown argument 'device=cpu'"),
        (["find the chair", "checkpoint="], "checkpoint= needs a value"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2_before_any_load(loads, capsys, argv, message):
    assert main(["read", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vla-gr read: error:") and message in err, err
    assert len(err.splitlines()) == 1
    assert loads.paths == []  # refused before loading anything


def test_the_arguments_and_their_help(loads, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["read"])  # TEXT is required
    assert exc.value.code == 2 and "text" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["read", "--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and "checkpoint=PATH" in out and DEFAULT_CHECKPOINT in out
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "read" in capsys.readouterr().out
    with pytest.raises(UserError, match="reads no requests"):  # --verbose: the error itself
        loads.policy = NoReader()
        main(["read", "find the chair", "--verbose"])


def test_module_entry():
    res = subprocess.run(
        [sys.executable, "-m", "vla_gr.read_cli", "--help"], capture_output=True, text=True
    )
    assert res.returncode == 0 and "checkpoint=PATH" in res.stdout
