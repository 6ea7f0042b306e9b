"""The end-to-end policy replays, bit for bit, the actions a tiny checkpoint gave before the
agent's redesign (``data/end_to_end_tiny``: ``vla-gr train --config-name config_debug``,
exported; ``data/end_to_end_tiny_actions.npz``: 24 observations of `val` episode 0 at 32 px
and the actions the policy chose for them under ``torch.manual_seed(0)``). Bit for bit on a
CPU with the recording's kernels; other CPUs (AVX-512 against AVX2 matmuls) differ in the
last float bits, so the check allows 1e-5 and asks the STOP decisions to agree exactly."""

from pathlib import Path

import numpy as np
import torch

from vla_gr.policy import load_policy

DATA = Path(__file__).parent / "data"


def test_end_to_end_reproduces_recorded_actions():
    policy = load_policy(DATA / "end_to_end_tiny")
    rec = np.load(DATA / "end_to_end_tiny_actions.npz")
    torch.manual_seed(0)
    policy.reset()
    actions = []
    for t in range(len(rec["actions"])):
        obs = {
            "rgb": rec["rgb"][t],  # (H, W, 3) uint8
            "depth": rec["depth"][t],  # (H, W, 1) float32
            "pose": rec["pose"][t],  # (3,)
            "instruction": str(rec["instruction"]),
        }
        actions.append(np.asarray(policy.select_action(obs), dtype=np.float32).reshape(3))
    actions = np.stack(actions)  # (T, 3)
    np.testing.assert_allclose(actions, rec["actions"], rtol=0, atol=1e-5)
    np.testing.assert_array_equal(actions[:, 2] > 0, rec["actions"][:, 2] > 0)  # STOP or not
