"""The safety filter node's ROS parameters: declared with descriptions and ranges, checked.

What each parameter means and how the values become ``NodeSettings`` is
``filter_parameters`` (no rclpy: bag replay and the evaluation build the same).  Here the
node's side: ``NODE_PARAMETERS``, the read-only ``model_params.*`` of its model, ``filter.*``
and ``scan_topics`` are declared (each only if it is not yet: a managed node configured again
keeps its values), read into settings, and a change that would make them invalid is refused
with the reason before it is applied.
"""
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from polyc2bf_ros.core.models import MODEL_NAMES, MODELS
from polyc2bf_ros.core.safety_filter import FilterConfig
from polyc2bf_ros.filter_parameters import (
    build_settings,
    FILTER_FIELDS,
    FILTER_PARAMETERS,
    model_parameters,
    NODE_PARAMETERS,
)


class NodeParameters:
    """The parameters of one configuration of the node (module docstring)."""

    def __init__(self, node):
        """Declare on ``node`` the parameters it does not have yet; read them into ``settings``.

        Raises ``ValueError`` (``filter_parameters.ParameterError``) for an invalid
        configuration, before anything but the parameters is created.
        """
        self._node = node
        self._declared = []
        for name, (default, bounds, text, read_only) in NODE_PARAMETERS.items():
            self._declare(name, default, bounds, text, read_only)
        model_name = node.get_parameter('model').value
        if model_name not in MODELS:
            raise ValueError(f"parameter 'model' must be one of {MODEL_NAMES}, "
                             f'got {model_name!r}')
        self._declare_model_and_filter_parameters(model_name)
        self._declare_scan_topics()
        self.settings = build_settings(self.values())  # those in use
        self._apply = None

    def watch(self, apply):
        """Check every parameter change first (refused with the reason), then ``apply`` it.

        ``apply(settings)`` gets the ``NodeSettings`` of the changed parameters, with a new
        filter for the same model.  The callbacks go with the node's configuration.
        """
        node, self._apply = self._node, apply
        node.add_on_set_parameters_callback(self._check)
        node._keep(node.remove_on_set_parameters_callback, self._check)
        node.add_post_set_parameters_callback(self._changed)
        node._keep(node.remove_post_set_parameters_callback, self._changed)

    def _check(self, params):
        """Refuse a change that makes the configuration invalid, with the reason.

        A change that leaves the filter's own values as they are builds no filter.
        """
        try:
            build_settings(self.values(params), self.settings.command_filter.model,
                           self.settings)
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _changed(self, params):
        """Rebuild the settings of the accepted parameters and apply them."""
        self.settings = build_settings(self.values(), self.settings.command_filter.model)
        self._apply(self.settings)

    def values(self, changes=()):
        """Return ``{name: value}`` of every parameter, overlaid with ``changes``."""
        node = self._node
        values = {p.name: p.value for p in node.get_parameters(self._declared)}
        try:
            values['scan_topics'] = list(node.get_parameter('scan_topics').value)
        except ParameterUninitializedException:  # declared without a value: no scans
            values['scan_topics'] = []
        values.update({p.name: p.value for p in changes})
        return values

    def _declare_model_and_filter_parameters(self, model_name):
        """Declare ``model_params.*`` (read-only, the model's constructor) and ``filter.*``."""
        for name, default in model_parameters(model_name).items():
            self._declare(f'model_params.{name}', default, None,
                          f'{model_name} model parameter {name!r}', True)
        defaults = FilterConfig()
        for name in FILTER_FIELDS:
            bounds, text = FILTER_PARAMETERS[name]
            self._declare(f'filter.{name}', getattr(defaults, name), bounds, text, False)

    def _declare_scan_topics(self):
        """Declare ``scan_topics`` (read-only, a string array with no default)."""
        if not self._node.has_parameter('scan_topics'):
            self._node.declare_parameter(
                'scan_topics', Parameter.Type.STRING_ARRAY, ParameterDescriptor(
                    name='scan_topics', read_only=True, description='sensor_msgs/LaserScan '
                    'topics to take obstacles from (empty: none); each has its own '
                    'scan_timeout watchdog; scans are placed by /tf_static from the odometry '
                    'child frame, else at sensor_pose'))

    def _declare(self, name, default, bounds, description, read_only):
        """Declare one parameter with its description and range, unless it already is.

        A managed node configured again keeps the parameters (and values) it has.
        """
        self._declared.append(name)
        if self._node.has_parameter(name):
            return
        descriptor = ParameterDescriptor(name=name, description=description, read_only=read_only)
        if bounds is not None and isinstance(default, int):
            descriptor.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1])]
        elif bounds is not None:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(bounds[0]), to_value=float(bounds[1]))]
        self._node.declare_parameter(name, default, descriptor)
