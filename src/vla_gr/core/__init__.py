"""The seed's building blocks, one package per concept.

Observation -> :mod:`.encoders` -> :mod:`.gr_field` -> :mod:`.dual_system` ->
:mod:`.diffusion_policy` (action head, built on :mod:`.trajectory_attention`);
:mod:`.peft_modules` fine-tunes any of them. :class:`vla_gr.policy.VLAGRPolicy` composes them.
"""
