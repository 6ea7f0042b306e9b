"""The GR field: the agent's map becomes mass, a Poisson potential, a conformal metric, a path.

Data flow: :mod:`.config` (``GRFieldConfig``, feature channels) -> :mod:`.mapping`
(depth -> allocentric evidence map) -> :mod:`.physics` (masses, potential, metric,
geodesics; pure maths) -> :mod:`.planning` (``GRField``: one update per planner tick,
waypoints and egocentric features; its allocentric layers and its output as :mod:`.field_maps`'
``FieldMaps`` and ``GRFieldOutput``) -> :mod:`.picture` (top-down image for reports).
The agent's behaviour on the field (look around, explore, approach, verify, recover, stop)
is :mod:`vla_gr.agent.navigator`.
"""

from vla_gr.core.gr_field.config import FEATURE_NAMES, GRFieldConfig
from vla_gr.core.gr_field.field_maps import FieldMaps, GRFieldOutput
from vla_gr.core.gr_field.mapping import update_map
from vla_gr.core.gr_field.physics import christoffel_conformal, integrate_geodesic, solve_poisson
from vla_gr.core.gr_field.picture import render_field
from vla_gr.core.gr_field.planning import GRField, snap_start

__all__ = [
    "FEATURE_NAMES",
    "FieldMaps",
    "GRField",
    "GRFieldConfig",
    "GRFieldOutput",
    "christoffel_conformal",
    "integrate_geodesic",
    "render_field",
    "snap_start",
    "solve_poisson",
    "update_map",
]
