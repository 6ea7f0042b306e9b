"""The machine a timing was taken on: CPU model, cores, and a one-thread reference speed."""

from __future__ import annotations

import os

import pytest
import torch

from vla_gr.machine import cpu_model, describe_machine, machine_line, reference_gflops


def test_reference_speed_is_positive_and_leaves_the_thread_count_alone():
    torch.set_num_threads(2)
    try:
        ref = reference_gflops(repeats=3)
        assert torch.get_num_threads() == 2  # measured on one thread, then restored
    finally:
        torch.set_num_threads(1)
    assert set(ref) == {"matmul_gflops", "conv_gflops"}
    assert all(0.0 < v < 1e5 for v in ref.values())
    with pytest.raises(ValueError, match="repeats"):
        reference_gflops(repeats=0)


def test_description_and_its_line_name_the_cpu_cores_and_reference():
    info = describe_machine()
    assert info["cpu"] == cpu_model() and info["cpu"]
    assert info["cores"] == os.cpu_count() and info["torch"] == torch.__version__
    assert len(info["load_average"]) == 3
    line = machine_line(info)
    assert info["cpu"] in line and f"{info['cores']} cores" in line
    assert f"{info['reference']['matmul_gflops']} GFLOP/s" in line
    quick = describe_machine(calibrate=False)
    assert "reference" not in quick and "GFLOP/s" not in machine_line(quick)
