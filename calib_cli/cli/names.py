"""Names and defaults the commands' help shows, kept here so that `calib --help` imports none of the
modules that define them (numba, pandas, OpenCV: a second of start-up). Stdlib only; each is a copy
that tests/test_startup.py holds equal to its source."""

from __future__ import annotations

#: calib_cli.dem.heap.PARAMETERS but the contact laws' own, which only their modules name (tests/test_laws.py):
#: what simulate-heap --set takes
HEAP_PARAMETERS = (
    "static_friction", "rolling_friction", "surface_energy", "restitution", "rolling_own_spin", "friction_net_force",
    "rolling_spring", "caps_pulloff", "wall_static_friction", "wall_rolling_friction", "wall_surface_energy",
    "wall_restitution", "cylinder_static_friction", "cylinder_rolling_friction", "cylinder_surface_energy",
    "cylinder_restitution",
)

#: the names of calib_cli.model.EFFECTS, in its order: what `calib model add|remove` take
EFFECT_NAMES = ("sliding_friction", "rolling_friction", "cohesion", "restitution", "wall_friction", "wall_rolling",
                "capillary")

#: calib_cli.imaging.measure.ShapeLimits' defaults: measure-angle's --max-flank-diff and --max-residual
MAX_FLANK_DIFF_DEG = 25.0
MAX_RESIDUAL = 0.20
