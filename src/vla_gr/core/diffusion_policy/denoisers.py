"""Denoising networks for the diffusion / flow action heads.

Both denoisers map a noisy action chunk, a (diffusion or flow) time and context
tokens to a chunk-shaped prediction, and split the work so that samplers can hoist
what does not change across integration steps out of their loop:

- ``embed_time(timesteps (N,)) -> (N, E)``: all step embeddings in one call;
- ``prepare_context(context (B, S, C), padding_mask) -> dict``: once per chunk;
- ``denoise(x (B, H, A), time_emb (B or 1, E), prepared) -> (B, H, A)``: per step.

``forward(x, timesteps, context)`` composes the three (used in training).

- :class:`ConditionalUnet1D` -- Diffusion Policy's 1-D temporal conv U-Net (Chi et al.
  2023): residual conv blocks with GroupNorm + Mish, FiLM (per-channel scale and bias)
  from ``[time embedding, pooled context]``, stride-2 down / transposed-conv up.
- :class:`TransformerDenoiser` -- action tokens with RoPE self-attention that
  cross-attend to ``[time token, context tokens]`` (built on
  :mod:`vla_gr.core.trajectory_attention`).

Next in the data flow: :mod:`vla_gr.core.diffusion_policy.unet_inference` (the U-Net's
batch-1 sampling step).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

from vla_gr.core.diffusion_policy.unet_inference import (
    FastConv1d,
    FastConvTranspose1d,
    UnetStepPlan,
)
from vla_gr.core.trajectory_attention.attention import TransformerBlock

__all__ = [
    "sinusoidal_embedding",
    "masked_mean",
    "ConditionalResidualBlock1D",
    "ConditionalUnet1D",
    "TransformerDenoiser",
]


def sinusoidal_embedding(timesteps: torch.Tensor, dim: int) -> torch.Tensor:
    """Transformer-style sinusoidal embedding of (possibly fractional) timesteps.

    Args:
        timesteps: ``(N,)`` float or integer timesteps.
        dim: even embedding size ``E``.

    Returns:
        ``(N, E)`` float32: ``[sin(t * w_k), cos(t * w_k)]``, ``w_k = 10000**(-k/(E/2-1))``.
    """
    if dim % 2 != 0 or dim < 4:
        raise ValueError(f"dim={dim} must be an even number >= 4")
    half = dim // 2
    scale = math.log(10000.0) / (half - 1)
    freqs = torch.exp(torch.arange(half, device=timesteps.device) * -scale)  # (E/2,)
    args = timesteps.float()[:, None] * freqs[None, :]  # (N, E/2)
    return torch.cat((args.sin(), args.cos()), dim=-1)  # (N, E)


def masked_mean(tokens: torch.Tensor, padding_mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean over tokens, ignoring padded ones.

    Args:
        tokens: ``(B, S, C)``.
        padding_mask: optional bool ``(B, S)``, ``True`` = padded.

    Returns:
        ``(B, C)``.
    """
    if padding_mask is None:
        return tokens.mean(dim=1)  # (B, C)
    keep = (~padding_mask.bool()).unsqueeze(-1).to(tokens.dtype)  # (B, S, 1)
    return (tokens * keep).sum(1) / keep.sum(1).clamp_min(1.0)  # (B, C)


class _Conv1dBlock(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish on ``(B, C, H)``."""

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, n_groups: int) -> None:
        super().__init__(
            FastConv1d(in_ch, out_ch, kernel_size, padding=kernel_size // 2),
            nn.GroupNorm(n_groups, out_ch),
            nn.Mish(),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, in_ch, H) -> (B, out_ch, H)`` (functional calls: less per-step overhead)."""
        norm = self[1]
        h = self[0](x)  # (B, out_ch, H)
        return F.mish(F.group_norm(h, norm.num_groups, norm.weight, norm.bias, norm.eps))


class ConditionalResidualBlock1D(nn.Module):
    """Two conv blocks with FiLM (``scale * h + bias``) from a conditioning vector.

    Args:
        in_ch: input channels.
        out_ch: output channels.
        cond_dim: conditioning vector size.
        kernel_size: temporal kernel size (odd).
        n_groups: GroupNorm groups (divides ``out_ch``).
    """

    def __init__(
        self, in_ch: int, out_ch: int, cond_dim: int, kernel_size: int = 5, n_groups: int = 8
    ) -> None:
        super().__init__()
        self.out_ch = out_ch
        self.block1 = _Conv1dBlock(in_ch, out_ch, kernel_size, n_groups)
        self.block2 = _Conv1dBlock(out_ch, out_ch, kernel_size, n_groups)
        self.cond_encoder = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * out_ch))
        self.residual = FastConv1d(in_ch, out_ch, 1) if in_ch != out_ch else nn.Identity()

    def film(
        self, cond: torch.Tensor, activated: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """FiLM ``(scale, bias)``, each ``(M, out_ch, 1)``, from ``cond (M, cond_dim)``.

        ``activated`` may pass ``Mish(cond)`` (shared by all blocks) to skip recomputing it.
        """
        if activated is not None and type(self.cond_encoder[0]) is nn.Mish:
            f = self.cond_encoder[1](activated)  # (M, 2 * o)
        else:
            f = self.cond_encoder(cond)  # (M, 2 * o)
        f = f.reshape(-1, 2, self.out_ch, 1)  # (M, 2, o, 1)
        return f[:, 0], f[:, 1]

    def film_grid(
        self, time_act: torch.Tensor, global_act: torch.Tensor, cond: Callable[[], torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """FiLM ``(scale, bias)``, each ``(N, B, out_ch, 1)``, for all (time, context) pairs.

        ``Linear(Mish([t, g])) = W_t Mish(t) + (W_g Mish(g) + b)`` as Mish is elementwise,
        so the context half runs once, not once per time (``N`` times fewer MACs).

        Args:
            time_act: ``(N, E)`` Mish of the time embeddings.
            global_act: ``(B, C)`` Mish of the pooled context.
            cond: returns the full ``(N * B, E + C)`` condition (used when the encoder is
                not exactly ``Mish -> Linear``, e.g. a LoRA-wrapped Linear).
        """
        N, B = time_act.shape[0], global_act.shape[0]
        act, lin = self.cond_encoder
        if type(act) is nn.Mish and type(lin) is nn.Linear:
            E = time_act.shape[1]
            f_g = F.linear(global_act, lin.weight[:, E:], lin.bias)  # (B, 2o)
            if B == 1:
                f = torch.addmm(f_g, time_act, lin.weight[:, :E].t())  # (N, 2o)
            else:
                f = torch.mm(time_act, lin.weight[:, :E].t())[:, None] + f_g  # (N, B, 2o)
        else:
            f = self.cond_encoder(cond())  # (N*B, 2o)
        f = f.reshape(N, B, 2, self.out_ch, 1)  # (N, B, 2, o, 1)
        return f[:, :, 0], f[:, :, 1]

    def forward(self, x: torch.Tensor, scale: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        """Apply the block.

        Args:
            x: ``(B, in_ch, H)``.
            scale: ``(B, out_ch, 1)`` FiLM scale (from :meth:`film`).
            bias: ``(B, out_ch, 1)`` FiLM bias.

        Returns:
            ``(B, out_ch, H)``.
        """
        h = torch.addcmul(bias, self.block1(x), scale)  # (B, out, H) = scale * h + bias
        return self.block2(h) + self.residual(x)  # (B, out, H)


class _Denoiser(nn.Module):
    """Shared training-time entry of the denoisers: embed time, prepare context, denoise.

    Subclasses provide ``embed_time``, ``prepare_context`` and ``denoise``; sampling loops
    call those directly so that per-chunk work is done once.
    """

    def forward(
        self,
        x: torch.Tensor,
        timesteps: torch.Tensor,
        context: torch.Tensor,
        context_padding_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Training-time prediction.

        Args:
            x: ``(B, H, A)`` noisy actions.
            timesteps: ``(B,)`` (float) timesteps.
            context: ``(B, S, C)`` context tokens.
            context_padding_mask: optional bool ``(B, S)``, ``True`` = padded.

        Returns:
            ``(B, H, A)``.
        """
        return self.denoise(
            x, self.embed_time(timesteps), self.prepare_context(context, context_padding_mask)
        )


class ConditionalUnet1D(_Denoiser):
    """Diffusion Policy's temporal U-Net with FiLM conditioning.

    The FiLM parameters of every block depend only on ``[time embedding, pooled
    context]``, so :meth:`step_conditions` computes them for all sampling steps in one
    batched pass; each step then runs only the convolutions.

    Args:
        action_dim: action size ``A`` (input/output channels).
        context_dim: context token width ``C`` (pooled, then concatenated with time).
        down_dims: channels per level; ``len(down_dims) - 1`` halvings of the horizon
            (horizons that are not a multiple of ``2**(levels-1)`` are zero-padded).
        time_embed_dim: sinusoidal time embedding size.
        kernel_size: temporal conv kernel (odd).
        n_groups: GroupNorm groups (must divide every entry of ``down_dims``).
        gradient_checkpointing: recompute residual blocks in backward.
    """

    def __init__(
        self,
        action_dim: int,
        context_dim: int,
        down_dims: tuple[int, ...] = (64, 128, 256),
        time_embed_dim: int = 128,
        kernel_size: int = 5,
        n_groups: int = 8,
        gradient_checkpointing: bool = False,
    ) -> None:
        super().__init__()
        down_dims = tuple(int(d) for d in down_dims)
        if not down_dims or any(d <= 0 or d % n_groups for d in down_dims):
            raise ValueError(
                f"down_dims={down_dims} must be non-empty multiples of n_groups={n_groups}"
            )
        if kernel_size % 2 != 1:
            raise ValueError(f"kernel_size={kernel_size} must be odd")
        self.action_dim, self.down_dims = action_dim, down_dims
        self.time_embed_dim = time_embed_dim
        self.gradient_checkpointing = gradient_checkpointing
        self.time_mlp = nn.Sequential(
            nn.Linear(time_embed_dim, 4 * time_embed_dim),
            nn.Mish(),
            nn.Linear(4 * time_embed_dim, time_embed_dim),
        )
        cond_dim = time_embed_dim + context_dim

        def res(d_in: int, d_out: int) -> ConditionalResidualBlock1D:
            return ConditionalResidualBlock1D(d_in, d_out, cond_dim, kernel_size, n_groups)

        dims = (action_dim, *down_dims)
        pairs = list(zip(dims[:-1], dims[1:]))
        self.downs = nn.ModuleList()
        for i, (d_in, d_out) in enumerate(pairs):
            last = i == len(pairs) - 1
            down = nn.Identity() if last else FastConv1d(d_out, d_out, 3, 2, 1)
            self.downs.append(nn.ModuleList([res(d_in, d_out), res(d_out, d_out), down]))
        mid = down_dims[-1]
        self.mids = nn.ModuleList([res(mid, mid), res(mid, mid)])
        self.ups = nn.ModuleList()
        for d_in, d_out in reversed(pairs[1:]):
            up = FastConvTranspose1d(d_in, d_in, 4, 2, 1)
            self.ups.append(nn.ModuleList([res(2 * d_out, d_in), res(d_in, d_in), up]))
        self.final = nn.Sequential(
            _Conv1dBlock(down_dims[0], down_dims[0], kernel_size, n_groups),
            FastConv1d(down_dims[0], action_dim, 1),
        )
        self._multiple = 2 ** (len(down_dims) - 1)
        self._res_blocks = [m for m in self.modules() if isinstance(m, ConditionalResidualBlock1D)]

    def embed_time(self, timesteps: torch.Tensor) -> torch.Tensor:
        """Time embeddings ``(N, time_embed_dim)`` of ``(N,)`` timesteps."""
        return self.time_mlp(sinusoidal_embedding(timesteps, self.time_embed_dim))  # (N, E)

    def prepare_context(
        self, context: torch.Tensor, padding_mask: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """Pool ``(B, S, C)`` context tokens to the global FiLM condition ``(B, C)``."""
        return {"global": masked_mean(context, padding_mask)}  # (B, C)

    def _films(self, cond: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """FiLM ``(scale, bias)`` ``(M, out_ch, 1)`` of every block from ``cond (M, E + C)``."""
        activated = F.mish(cond)  # (M, E + C), the first layer of every cond_encoder
        return [blk.film(cond, activated) for blk in self._res_blocks]

    def step_conditions(
        self, time_embs: torch.Tensor, prepared: dict[str, torch.Tensor]
    ) -> list[list[torch.Tensor]]:
        """Per-step FiLM parameters for ``N`` sampling steps, in one batched pass.

        Args:
            time_embs: ``(N, E)`` from :meth:`embed_time`.
            prepared: output of :meth:`prepare_context` (``global``: ``(B, C)``).

        Returns:
            ``N`` lists (one per step) of per-block FiLM ``(scale, bias)``, each
            ``(B, out_ch, 1)``, for :meth:`denoise_step`.
        """
        g = prepared["global"]  # (B, C)
        N, B = time_embs.shape[0], g.shape[0]
        cond = functools.cache(
            lambda: torch.cat(
                (time_embs[:, None].expand(N, B, -1), g[None].expand(N, B, -1)), dim=-1
            ).view(N * B, -1)
        )  # () -> (N*B, E + C), built only if some block needs it
        time_act, global_act = F.mish(time_embs), F.mish(g)  # (N, E), (B, C)
        # One unbind per tensor here saves slicing ops inside every sampling step.
        per_block = [
            zip(scale.unbind(0), bias.unbind(0))  # N x (B, o, 1) each
            for scale, bias in (
                blk.film_grid(time_act, global_act, cond) for blk in self._res_blocks
            )
        ]
        return [list(step) for step in zip(*per_block)]

    def _block(
        self, blk: nn.Module, x: torch.Tensor, film: tuple[torch.Tensor, torch.Tensor]
    ) -> torch.Tensor:
        if self.gradient_checkpointing and self.training and torch.is_grad_enabled():
            return checkpoint(blk, x, *film, use_reentrant=False)
        return blk(x, *film)

    def denoise_step(self, x: torch.Tensor, films: list[torch.Tensor]) -> torch.Tensor:
        """Run the U-Net with precomputed FiLM parameters.

        Args:
            x: ``(B, H, A)`` noisy actions.
            films: per-block FiLM ``(scale, bias)``, each ``(B, out_ch, 1)`` (see
                :meth:`step_conditions`).

        Returns:
            ``(B, H, A)``.
        """
        H = x.shape[1]
        pad = (-H) % self._multiple
        h = x.transpose(1, 2)  # (B, A, H)
        if pad:
            h = F.pad(h, (0, pad))  # (B, A, H + pad)
        it = iter(films)
        skips = []
        for res1, res2, down in self.downs:
            h = self._block(res2, self._block(res1, h, next(it)), next(it))  # (B, d, L)
            skips.append(h)
            h = down(h)  # (B, d, L/2)
        for res in self.mids:
            h = self._block(res, h, next(it))  # (B, d_mid, L)
        for res1, res2, up in self.ups:
            h = torch.cat((h, skips.pop()), dim=1)  # (B, 2d, L)
            h = up(self._block(res2, self._block(res1, h, next(it)), next(it)))  # (B, d', 2L)
        out = self.final(h)  # (B, A, H + pad)
        return out[..., :H].transpose(1, 2)  # (B, H, A)

    def sampling_step(self, x: torch.Tensor) -> Callable:
        """The per-step function for a sampling loop over chunks shaped like ``x``.

        At batch 1 this is a
        :class:`~vla_gr.core.diffusion_policy.unet_inference.UnetStepPlan` (same maths,
        about half the per-op overhead), built now from views of the current parameters,
        so call it once per chunk; otherwise (or for modules it does not
        know, e.g. convs wrapped by unmerged LoRA) :meth:`denoise_step`.

        Args:
            x: ``(B, H, A)`` initial noisy actions.

        Returns:
            ``(x (B, H, A), films) -> (B, H, A)`` taking :meth:`step_conditions` entries.
        """
        return UnetStepPlan.build(self, x) or self.denoise_step

    def denoise(
        self, x: torch.Tensor, time_emb: torch.Tensor, prepared: dict[str, torch.Tensor]
    ) -> torch.Tensor:
        """Predict from noisy actions.

        Args:
            x: ``(B, H, A)`` noisy actions.
            time_emb: ``(B, E)`` or ``(1, E)`` from :meth:`embed_time`.
            prepared: output of :meth:`prepare_context` (``global``: ``(B, C)``).

        Returns:
            ``(B, H, A)``.
        """
        g = prepared["global"]  # (B, C)
        cond = torch.cat((time_emb.expand(g.shape[0], -1), g), dim=-1)  # (B, E + C)
        return self.denoise_step(x, self._films(cond))


class TransformerDenoiser(_Denoiser):
    """Action tokens that self-attend (RoPE) and cross-attend to ``[time, context]`` tokens.

    Args:
        action_dim: action size ``A``.
        context_dim: context token width ``C``.
        hidden_dim: model width ``D``.
        num_layers: pre-norm transformer blocks.
        num_heads: attention heads.
        mlp_ratio: MLP width multiple.
        dropout: dropout probability.
        gradient_checkpointing: recompute blocks in backward.
    """

    def __init__(
        self,
        action_dim: int,
        context_dim: int,
        hidden_dim: int = 128,
        num_layers: int = 4,
        num_heads: int = 4,
        mlp_ratio: float = 4.0,
        dropout: float = 0.0,
        gradient_checkpointing: bool = False,
    ) -> None:
        super().__init__()
        self.hidden_dim, self.gradient_checkpointing = hidden_dim, gradient_checkpointing
        self.time_embed_dim = hidden_dim
        self.time_mlp = nn.Sequential(
            nn.Linear(hidden_dim, 4 * hidden_dim), nn.Mish(), nn.Linear(4 * hidden_dim, hidden_dim)
        )
        self.action_in = nn.Linear(action_dim, hidden_dim)
        self.context_proj = nn.Linear(context_dim, hidden_dim)
        self.blocks = nn.ModuleList(
            TransformerBlock(hidden_dim, num_heads, hidden_dim, mlp_ratio, dropout, True, False)
            for _ in range(num_layers)
        )
        self.norm = nn.LayerNorm(hidden_dim)
        self.action_out = nn.Linear(hidden_dim, action_dim)

    def embed_time(self, timesteps: torch.Tensor) -> torch.Tensor:
        """Time embeddings ``(N, D)`` of ``(N,)`` timesteps."""
        return self.time_mlp(sinusoidal_embedding(timesteps, self.hidden_dim))  # (N, D)

    def prepare_context(
        self, context: torch.Tensor, padding_mask: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor | None]:
        """Project ``(B, S, C)`` context tokens to ``(B, S, D)`` memory (+ mask with time slot)."""
        mem = self.context_proj(context)  # (B, S, D)
        mask = None
        if padding_mask is not None:
            time_slot = torch.zeros_like(padding_mask[:, :1], dtype=torch.bool)  # (B, 1)
            mask = torch.cat((time_slot, padding_mask.bool()), dim=1)  # (B, 1 + S)
        return {"memory": mem, "mask": mask}

    def step_conditions(
        self, time_embs: torch.Tensor, prepared: dict[str, torch.Tensor | None]
    ) -> list[dict]:
        """Per-step conditioning for ``N`` sampling steps, batched over the steps.

        The memory ``[time token, context]`` of step ``i`` is fixed, so each block's
        cross-attention keys/values are projected once for all steps here.

        Args:
            time_embs: ``(N, D)`` from :meth:`embed_time`.
            prepared: output of :meth:`prepare_context`.

        Returns:
            ``N`` dicts for :meth:`denoise_step`.
        """
        mem = prepared["memory"]  # (B, S, D)
        N, (B, S, D) = time_embs.shape[0], mem.shape
        t = time_embs[:, None, None, :].expand(N, B, 1, D)  # (N, B, 1, D)
        memory = torch.cat((t, mem[None].expand(N, B, S, D)), dim=2)  # (N, B, 1 + S, D)
        flat = memory.reshape(N * B, S + 1, D)  # (N*B, 1 + S, D)
        kvs = []
        for block in self.blocks:
            k, v = block.cross_attn.project_kv(flat)  # (N*B, h, 1 + S, d) each
            kvs.append((k.unflatten(0, (N, B)), v.unflatten(0, (N, B))))  # (N, B, h, 1+S, d)
        return [
            {
                "t": t[i],
                "mask": prepared["mask"],
                "kv": [(k[i], v[i]) for k, v in kvs],
            }
            for i in range(N)
        ]

    def denoise_step(self, x: torch.Tensor, cond: dict) -> torch.Tensor:
        """Run the blocks with precomputed conditioning.

        Args:
            x: ``(B, H, A)`` noisy actions.
            cond: ``t``: ``(B, 1, D)`` time token; ``mask``: ``(B, 1 + S)`` or ``None``;
                and either ``memory``: ``(B, 1 + S, D)`` or ``kv``: per-block
                cross-attention ``(k, v)``, each ``(B, heads, 1 + S, head_dim)``.

        Returns:
            ``(B, H, A)``.
        """
        memory, mask, kvs = cond.get("memory"), cond["mask"], cond.get("kv")
        h = self.action_in(x) + cond["t"]  # (B, H, D)
        use_ckpt = self.gradient_checkpointing and self.training and torch.is_grad_enabled()
        for i, block in enumerate(self.blocks):
            if kvs is not None:
                h = block(h, None, mask, context_kv=kvs[i])  # (B, H, D)
            elif use_ckpt:
                h = checkpoint(block, h, memory, mask, use_reentrant=False)
            else:
                h = block(h, memory, mask)  # (B, H, D)
        return self.action_out(self.norm(h))  # (B, H, A)

    def sampling_step(self, x: torch.Tensor) -> Callable:
        """The per-step function of a sampling loop: :meth:`denoise_step` (``x``: ``(B, H, A)``)."""
        return self.denoise_step

    def denoise(
        self, x: torch.Tensor, time_emb: torch.Tensor, prepared: dict[str, torch.Tensor | None]
    ) -> torch.Tensor:
        """Predict from noisy actions.

        Args:
            x: ``(B, H, A)`` noisy actions.
            time_emb: ``(B, D)`` or ``(1, D)`` from :meth:`embed_time`.
            prepared: output of :meth:`prepare_context`.

        Returns:
            ``(B, H, A)``.
        """
        t = time_emb.expand(x.shape[0], -1).unsqueeze(1)  # (B, 1, D)
        memory = torch.cat((t, prepared["memory"]), dim=1)  # (B, 1 + S, D)
        return self.denoise_step(x, {"t": t, "memory": memory, "mask": prepared["mask"]})
