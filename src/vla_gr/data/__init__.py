"""vla_gr.data."""
