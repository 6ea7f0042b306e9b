"""vla_gr.envs."""
