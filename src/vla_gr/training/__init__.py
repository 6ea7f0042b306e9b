"""Helpers of ``vla_gr.train``: distribution, data, optimisation, EMA, logging, the loop
state and its checkpoint (saved with ``vla_gr.checkpoint``)."""
