"""The ``safety_filter`` node's parameters without ROS: rcl YAML files -> ``CommandFilter``.

Offline bag replay and the in-process evaluation decide exactly as the node does,
so they build the node's ``CommandFilter`` from the same parameter files
(``--params-file``), with the node's defaults (``NODE_PARAMETERS``) for the rest
and ``model_params.*`` / ``filter.*`` as the node declares them.  rcl's file
format: top-level keys are node name patterns (``/**`` any namespaces, ``*`` one
token) holding ``ros__parameters``; nested mappings flatten to dotted names.
"""
import dataclasses
import re
from pathlib import Path

import yaml

from polyc2bf_ros.core.command_filter import CommandFilter
from polyc2bf_ros.core.models import make_model, MODEL_NAMES, MODELS
from polyc2bf_ros.core.safety_filter import FilterConfig
from polyc2bf_ros.safety_filter_node import NODE_PARAMETERS

NODE_NAME = 'safety_filter'


class ParameterError(ValueError):
    """An unreadable parameter file or an invalid parameter value, with the reason."""


def _node_pattern(key):
    """Regex of an rcl parameter-file node key (``/**`` any namespaces, ``*`` one token)."""
    key = '/' + key.lstrip('/')
    parts = []
    for token in key.split('/')[1:]:
        if token == '**':
            parts.append('(?:/[^/]+)*')
        else:
            parts.append('/' + re.escape(token).replace(r'\*', '[^/]*'))
    return re.compile(''.join(parts) + '$')


def _flatten(values, prefix=''):
    flat = {}
    for key, value in values.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f'{prefix}{key}.'))
        else:
            flat[f'{prefix}{key}'] = value
    return flat


def load_parameters(params_files, overrides, namespace):
    """Return ``{name: value}`` for node ``/namespace/safety_filter`` from rcl YAML files.

    Every section whose node pattern matches is applied in file order; then
    the ``NAME:=VALUE`` ``overrides`` (values parsed as YAML, like ``-p``).
    """
    fqn = f'/{namespace.strip("/")}/{NODE_NAME}' if namespace.strip('/') else f'/{NODE_NAME}'
    values = {}
    for path in params_files or ():
        try:
            data = yaml.safe_load(Path(path).read_text()) or {}
        except OSError as exc:
            raise ParameterError(f'cannot read parameter file {path}: {exc.strerror}') from None
        except yaml.YAMLError as exc:
            raise ParameterError(f'parameter file {path} is not YAML: {exc}') from None
        for key, section in data.items():
            if not isinstance(section, dict) or 'ros__parameters' not in section:
                raise ParameterError(f'{path}: section {key!r} has no ros__parameters')
            if _node_pattern(str(key)).match(fqn):
                values.update(_flatten(section['ros__parameters'] or {}))
    for item in overrides or ():
        name, sep, text = item.partition(':=')
        if not (sep and name):
            raise ParameterError(f'parameter {item!r} is not NAME:=VALUE')
        values[name] = yaml.safe_load(text)
    return values


@dataclasses.dataclass
class FilterSetup:
    """The node's decision, built from its parameters: filter and message-side settings.

    ``ignored`` lists parameter names the node does not declare (callers report them).
    """

    command_filter: object
    model_name: str
    parameters: dict
    max_extrapolation: float
    wall_thickness: float
    cylinder_sides: int
    ignored: tuple = ()


def build_filter(parameters):
    """Build ``CommandFilter`` and settings as the node does from ``parameters``.

    Missing parameters take the node's defaults; unknown names end up in ``ignored``.
    """
    values = {name: spec[0] for name, spec in NODE_PARAMETERS.items()}
    fields = [f.name for f in dataclasses.fields(FilterConfig) if f.name != 'control_period']
    model_params, filter_params, unknown = {}, {}, []
    for name, value in parameters.items():
        group, _, field = name.partition('.')
        if name in values:
            values[name] = value
        elif group == 'model_params' and field:
            model_params[field] = value
        elif group == 'filter' and field in fields:
            filter_params[field] = value
        else:
            unknown.append(name)
    model_name = values['model']
    if model_name not in MODELS:
        raise ParameterError(f"parameter 'model' must be one of {MODEL_NAMES}, got {model_name!r}")
    try:
        model = make_model(model_name, **model_params)
        rate = float(values['rate'])
        if not rate > 0.0:
            raise ValueError(f'rate must be positive, got {rate}')
        config = FilterConfig(control_period=1.0 / rate, **filter_params).validate()
        command_filter = CommandFilter(model, config, float(values['velocity_tau']))
    except (TypeError, ValueError) as exc:
        raise ParameterError(f'invalid filter parameters: {exc}') from None
    values.update({f'model_params.{k}': v for k, v in model_params.items()})
    values.update({f'filter.{k}': getattr(config, k) for k in fields})
    return FilterSetup(command_filter, model_name, values, float(values['max_extrapolation']),
                       float(values['wall_thickness']), int(values['cylinder_sides']),
                       tuple(sorted(unknown)))
