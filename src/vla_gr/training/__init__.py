"""Helpers of ``vla_gr.train``: distribution, optimisation, EMA, checkpoints, logging, data."""
