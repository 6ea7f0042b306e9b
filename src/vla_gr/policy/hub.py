"""The policies in huggingface_hub's conventions (``PyTorchModelHubMixin``, as LeRobot's
policies have them): ``policy.save_pretrained(folder)`` writes a pretrained folder and
``NavigationPolicy.from_pretrained(folder or repo id)`` reads it back as the class it names.

A pretrained folder holds ``model.safetensors`` (the weights), ``config.json`` (every model
key), ``README.md`` (a model card) and ``manifest.json`` (the SHA-256 of each, checked before
anything is parsed; see :mod:`vla_gr.checkpoint`). Loading never unpickles. A training
checkpoint (``<run>/checkpoints/best``, the shipped ``checkpoints/vla_gr_cpu``) loads the same
way, and ``save_pretrained`` of its policy writes it as a pretrained folder.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import torch
from huggingface_hub import ModelCard, PyTorchModelHubMixin, snapshot_download
from huggingface_hub.utils import HFValidationError, validate_repo_id
from omegaconf import OmegaConf

from vla_gr.checkpoint import CheckpointError, save_folder, write_pretrained_files

__all__ = ["MODEL_CARD", "PolicyHubMixin", "resolve_pretrained"]

log = logging.getLogger(__name__)

#: The model card (``README.md``) of a pretrained folder, a jinja template as the mixin takes.
MODEL_CARD = """---
{{ card_data }}
---

# {{ class_name }}: a VLA-GR navigation policy (`model.agent={{ agent }}`)

A language-conditioned navigation policy ({{ parameters }} parameters) saved in
huggingface_hub's `PyTorchModelHubMixin` layout: `config.json` holds every model key,
`model.safetensors` the weights and `manifest.json` the SHA-256 of every file, checked before
loading.

```python
from vla_gr.policy import NavigationPolicy

policy = NavigationPolicy.from_pretrained("<this folder or its repo id>")
action = policy.select_action(obs)  # obs of gymnasium.make("VLAGR/ObjectNav-v0")
```
"""


class PolicyHubMixin(
    PyTorchModelHubMixin,
    library_name="vla-gr",
    license="apache-2.0",
    tags=["robotics", "navigation", "vla-gr"],
    model_card_template=MODEL_CARD,
):
    """``save_pretrained`` / ``from_pretrained`` of a
    :class:`~vla_gr.policy.base.NavigationPolicy` (an ``nn.Module`` with ``config``, its
    ``ModelConfig``)."""

    def _save_pretrained(self, save_directory: Path) -> None:
        """The mixin's hook: ``model.safetensors`` and ``config.json`` into the folder."""
        config = OmegaConf.to_container(OmegaConf.structured(self.config))
        write_pretrained_files(Path(save_directory), self.state_dict(), config)

    def save_pretrained(
        self,
        save_directory: str | Path,
        *,
        config: None = None,
        repo_id: str | None = None,
        push_to_hub: bool = False,
        model_card_kwargs: dict | None = None,
        **push_to_hub_kwargs,
    ) -> str | None:
        """Write pretrained folder ``save_directory`` whole (an existing checkpoint there is
        replaced, any other existing path refused): the mixin's files, then ``manifest.json``
        (then the ONNX export of the perception when ``model.perception.engine=onnxruntime``).
        ``push_to_hub`` then uploads it as huggingface_hub's ``push_to_hub`` does (its URL is
        returned); ``config.json`` is always ``self.config``, so ``config`` must be None."""
        if config is not None:
            raise ValueError(
                "save_pretrained writes the policy's own config (policy.config) as config.json; "
                "pass no config"
            )
        write = super().save_pretrained  # _save_pretrained, then the model card

        def fill(folder: Path) -> None:
            write(folder, model_card_kwargs=model_card_kwargs)

        folder = save_folder(save_directory, fill)
        if self.config.perception.engine == "onnxruntime":  # what its perception runs
            from vla_gr.policy.onnx_export import export_onnx

            export_onnx(folder)
        log.info("pretrained %s saved to %s", type(self).__name__, folder)
        if push_to_hub:
            repo = repo_id or folder.name
            return self.push_to_hub(repo, model_card_kwargs=model_card_kwargs, **push_to_hub_kwargs)
        return None

    def generate_model_card(self, *args, **kwargs) -> ModelCard:
        """The mixin's card from :data:`MODEL_CARD`, naming this policy's class, agent, size."""
        values = {
            "class_name": type(self).__name__,
            "agent": self.config.agent,
            "parameters": f"{sum(p.numel() for p in self.parameters()):,}",
        }
        return super().generate_model_card(*args, **(values | kwargs))

    @classmethod
    def from_pretrained(
        cls,
        pretrained_model_name_or_path: str | Path,
        device: torch.device | str = "cpu",
        overrides: Sequence[str] = (),
        *,
        force_download: bool = False,
        token: str | bool | None = None,
        cache_dir: str | Path | None = None,
        local_files_only: bool = False,
        revision: str | None = None,
    ):
        """The agent of a pretrained folder or checkpoint folder, or of a Hub repo id (its
        snapshot in the local Hugging Face cache; see :func:`resolve_pretrained`), verified
        against its manifest, in eval mode on ``device``: the class its ``model.agent`` names,
        which must be a ``cls`` (``NavigationPolicy`` takes any agent). ``overrides``
        (``"navigator.confirmation.ticks=3"``) change settings no weight depends on (see
        :func:`vla_gr.policy.factory.load_policy`); the other arguments are the mixin's."""
        from vla_gr.policy.factory import load_policy

        folder = resolve_pretrained(
            pretrained_model_name_or_path,
            force_download=force_download,
            token=token,
            cache_dir=cache_dir,
            local_files_only=local_files_only,
            revision=revision,
        )
        return load_policy(folder, device=device, overrides=overrides, expected=cls)


def resolve_pretrained(name_or_path: str | Path, **hub_kwargs) -> Path:
    """The local folder of ``name_or_path``: the path itself when it exists or is no repo id
    (the loader then says what is wrong with it); else the snapshot of Hub repo
    ``name_or_path`` in the Hugging Face cache (``snapshot_download(**hub_kwargs)``: read from
    the cache when offline or ``local_files_only``). CheckpointError in one line when neither."""
    path = Path(name_or_path)
    if path.exists() or path.is_symlink() or not _is_repo_id(str(name_or_path)):
        return path
    try:
        return Path(snapshot_download(str(name_or_path), **hub_kwargs))
    except OSError as err:  # huggingface_hub's errors: not cached, no such repo, no network
        reason = (str(err).splitlines() or [""])[0]
        raise CheckpointError(
            f"checkpoint {name_or_path}: no such folder, nor a Hugging Face Hub model of that id "
            f"({type(err).__name__}: {reason})"
        ) from None


def _is_repo_id(name: str) -> bool:
    """Whether ``name`` is written like a Hub repo id (``name`` or ``owner/name``)."""
    try:
        validate_repo_id(name)
    except HFValidationError:
        return False
    return True
