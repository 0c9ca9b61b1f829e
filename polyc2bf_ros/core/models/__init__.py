"""Robot models behind one interface; ``make_model(name, **params)`` builds one.

Also the Crazyflie 2.1's constants (``crazyflie``).  Imports only ``kernels``.

Adding a model is one new file that subclasses ``RobotModel``, decorates it
with ``@register_model`` and is imported here.
"""
from polyc2bf_ros.core.models import point_mass, quadrotor, unicycle  # noqa: F401
from polyc2bf_ros.core.models.base import MODELS, ReferenceKinematics, RobotModel

MODEL_NAMES = tuple(sorted(MODELS))


def make_model(name, **params) -> RobotModel:
    """Build the model registered as ``name`` with keyword parameters."""
    try:
        cls = MODELS[name]
    except KeyError:
        raise ValueError(f'unknown model {name!r}; choose one of {", ".join(MODEL_NAMES)}')
    return cls(**params)


__all__ = ['MODEL_NAMES', 'MODELS', 'ReferenceKinematics', 'RobotModel', 'make_model']
