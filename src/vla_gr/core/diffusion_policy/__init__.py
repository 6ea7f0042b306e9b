"""The action head: context tokens -> action chunks ``(B, H, A)``.

Data flow: :mod:`.config` (``HeadConfig``, the option lists) -> :mod:`.head`
(``DiffusionPolicy``: training loss and sampling loop), which uses the pure maths of
:mod:`.flow_matching` (pi0 flow matching) and :mod:`.noise_targets` (DDPM targets), a
denoiser from :mod:`.denoisers` (1-D U-Net or transformer; the U-Net's batch-1 step plan
is :mod:`.unet_inference`), or the one-pass L1 head of :mod:`.regression_head`.
"""

from vla_gr.core.diffusion_policy.config import (
    DENOISERS,
    OBJECTIVES,
    PREDICTION_TYPES,
    SAMPLERS,
    HeadConfig,
)
from vla_gr.core.diffusion_policy.denoisers import ConditionalUnet1D, TransformerDenoiser
from vla_gr.core.diffusion_policy.head import FLOW_TIME_SCALE, DiffusionPolicy
from vla_gr.core.diffusion_policy.regression_head import L1RegressionHead

__all__ = [
    "DENOISERS",
    "FLOW_TIME_SCALE",
    "OBJECTIVES",
    "PREDICTION_TYPES",
    "SAMPLERS",
    "ConditionalUnet1D",
    "DiffusionPolicy",
    "HeadConfig",
    "L1RegressionHead",
    "TransformerDenoiser",
]
