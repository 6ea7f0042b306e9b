"""run_command: argument parsing, the UserError exit and the torch thread limit."""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator

import pytest
import torch

from vla_gr.errors import UserError
from vla_gr.training.command import run_command


@pytest.fixture(autouse=True)
def _keep_threads() -> Iterator[int]:
    before = torch.get_num_threads()
    try:
        yield before
    finally:
        torch.set_num_threads(before)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="prog-name")
    parser.add_argument("name")
    parser.add_argument("--count", type=int, default=1)
    return parser


def test_user_error_is_one_stderr_line_and_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    def work(args: argparse.Namespace) -> None:
        raise UserError("bad thing")

    assert run_command(_parser(), ["x"], work) == 2
    captured = capsys.readouterr()
    assert captured.err == "prog-name: error: bad thing\n"
    assert captured.out == ""


def test_success_is_0_and_work_gets_the_parsed_args(capsys: pytest.CaptureFixture[str]) -> None:
    seen: list[argparse.Namespace] = []

    def work(args: argparse.Namespace) -> int:
        seen.append(args)
        print("done")
        return 5  # ignored

    assert run_command(_parser(), ["abc", "--count", "7"], work, limit_threads=False) == 0
    assert len(seen) == 1
    assert seen[0].name == "abc"
    assert seen[0].count == 7
    captured = capsys.readouterr()
    assert captured.out == "done\n"
    assert captured.err == ""


def test_other_exceptions_propagate() -> None:
    def work(args: argparse.Namespace) -> None:
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        run_command(_parser(), ["x"], work, limit_threads=False)


def test_bad_arguments_exit_through_argparse(capsys: pytest.CaptureFixture[str]) -> None:
    def work(args: argparse.Namespace) -> None:
        raise AssertionError("work must not run")

    with pytest.raises(SystemExit) as exc:
        run_command(_parser(), ["x", "--count", "many"], work)
    assert exc.value.code == 2
    assert "prog-name: error:" in capsys.readouterr().err


def test_limit_threads_caps_torch_at_two(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    torch.set_num_threads(3)
    assert run_command(_parser(), ["x"], lambda args: None, limit_threads=True) == 0
    assert torch.get_num_threads() == 2


def test_limit_threads_on_one_cpu_uses_one(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    torch.set_num_threads(3)
    assert run_command(_parser(), ["x"], lambda args: None, limit_threads=True) == 0
    assert torch.get_num_threads() == 1


def test_no_limit_leaves_torch_threads_alone() -> None:
    torch.set_num_threads(3)
    assert run_command(_parser(), ["x"], lambda args: None, limit_threads=False) == 0
    assert torch.get_num_threads() == 3
