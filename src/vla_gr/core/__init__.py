"""vla_gr.core."""
