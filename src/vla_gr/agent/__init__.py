"""The VLA-GR agent's own parts, apart from the reusable building blocks of :mod:`vla_gr.core`.

One observation's walk (see the README's "The agent"): :mod:`.perception` turns it into one
typed percept per S2 tick (the instruction read once per episode; goal likelihood, room and
object checks, the relation's anchor) -> :mod:`.navigator` plans on the GR field
(:mod:`vla_gr.core.gr_field`) -> a follower of :mod:`.followers` (pure pursuit or the learned
S1) acts every control step; :mod:`.dual_system` schedules the two. The policies that own these
parts are :mod:`vla_gr.policy`.
"""
