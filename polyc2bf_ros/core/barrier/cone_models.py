"""The cone models by name, and the factory the filter builds its model with.

Adding a model is one new file with a ``ConeModel`` subclass (``polyc2bf_ros.core.barrier.cones``)
and one entry here.
"""
import math

from polyc2bf_ros.core.barrier.cones import CircleCone, ConeModel, InflatedCone, PaperCone
from polyc2bf_ros.core.barrier.horizon_cone import AXES, HorizonCone

CONE_MODELS = {cls.name: cls for cls in (PaperCone, InflatedCone, CircleCone, HorizonCone)}
CONE_AXES = AXES


def make_cone_model(name, robot_radius, segments=16, horizon=math.inf,
                    axis='bisector') -> ConeModel:
    """Build the cone model called ``name``; each takes the settings it uses."""
    if name == InflatedCone.name:
        return InflatedCone(robot_radius, segments)
    if name == HorizonCone.name:
        return HorizonCone(robot_radius, segments, horizon, axis)
    if name not in CONE_MODELS:
        raise ValueError(f'unknown barrier {name!r}; choose one of {", ".join(CONE_MODELS)}')
    return CONE_MODELS[name](robot_radius)
