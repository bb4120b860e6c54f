"""Declaring the parameter tables (eqhrl_ros/parameters.py) on an rclpy node.

rclpy checks each value against its descriptor when the node starts (from a
params file or --ros-args -p) and on every set_parameters call, and refuses a
value out of range or of the wrong type with a message naming the parameter.
"""

from __future__ import annotations

import array
import os
import sys

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..parameters import BUILT_IN, Param, flat_sections, section_applies


def descriptor(param: Param) -> ParameterDescriptor:
    """The rclpy descriptor of a parameter: its description, choices, range and whether it may change."""
    text = param.description
    if param.choices:
        text += f' (one of: {", ".join(param.choices)})'
    result = ParameterDescriptor(description=text, read_only=not param.dynamic)
    if param.range is not None:
        low, high = param.range
        if isinstance(param.default, int):
            result.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
        elif isinstance(param.default, float):
            result.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
    return result


UNSET_KINDS = {
    'double_array': Parameter.Type.DOUBLE_ARRAY,
    'integer_array': Parameter.Type.INTEGER_ARRAY,
    'string_array': Parameter.Type.STRING_ARRAY,
}


def plain(value):
    """A parameter's value as it was given: rclpy hands a changed array as array.array
    (`array('d', [3.0])` in a log line or a refusal); a list instead."""
    return value.tolist() if isinstance(value, array.array) else value


def declare(node: Node, params: tuple[Param, ...]) -> dict:
    """Declare every parameter; return {name: value}. Bad values raise with the name in the message.

    A parameter with no default (an array whose absence means something: the spaces from env_id)
    is declared only when a params file or -p gives it, else its value is None. rclpy can declare
    no empty array (it would be typed as bytes), and one declared typed but unset made the node's
    get_parameters answer nothing at all: `ros2 param dump` printed no parameter of any shipped
    node, and `ros2 param get` of an unset one failed."""
    values = {}
    given = getattr(node, '_parameter_overrides', {})  # rclpy keeps a params file's and -p's values here
    for param in params:
        if param.default is None and param.name not in given:
            values[param.name] = None
            continue
        default = UNSET_KINDS[param.kind] if param.default is None else param.default
        value = node.declare_parameter(param.name, default, descriptor(param)).value
        if value is None and (isinstance(param.default, list) or param.kind in UNSET_KINDS):
            value = []  # given as [] (rcl leaves an empty array unset): empty, not None (`axes:=[]` crashed)
        if param.kind == 'double_array' and value is not None:
            value = [float(v) for v in value]
        if param.kind == 'integer_array' and value is not None:
            value = [int(v) for v in value]
        if param.kind == 'string_array' and value is not None:
            value = [str(v) for v in value]
        if param.path and value is not None:
            value = [os.path.expanduser(v) for v in value] if isinstance(value, list) else os.path.expanduser(value)
        if param.choices and value not in param.choices:
            raise ValueError(f"parameter '{param.name}' is {value!r}; expected one of {param.choices}")
        values[param.name] = value
    _values_as_set(node).update(values)
    return values


def _values_as_set(node: Node) -> dict:
    """The node's parameter values as last set, kept so that each run-time change is logged with the
    value it replaced: rclpy's parameter services do not say who calls them, so any node on the graph
    may set one (`ros2 param set`, the page's budget fields), and the node's log is where its person
    sees that it happened (before: a change was applied without a word)."""
    known = getattr(node, '_eqhrl_values_as_set', None)
    if known is None:
        known = node._eqhrl_values_as_set = {}

        def said(changes) -> None:
            for change in changes:
                if change.name in known:  # not one being declared now (rclpy calls this for those too)
                    node.get_logger().info(
                        f'parameter {change.name} set to {plain(change.value)!r} (was {known[change.name]!r})'
                    )
                known[change.name] = plain(change.value)

        node.add_post_set_parameters_callback(said)
    return known


def choices_validator(params: tuple[Param, ...]):
    """An on-set-parameters callback refusing strings outside a parameter's choices."""
    by_name = {p.name: p for p in params}

    def validate(changes) -> SetParametersResult:
        for change in changes:
            if not change.name or not change.name.strip():
                return SetParametersResult(successful=False, reason='a parameter needs a name')
            param = by_name.get(change.name)
            if param and param.choices and change.value not in param.choices:
                return SetParametersResult(successful=False, reason=f"'{change.name}' must be one of {param.choices}")
        return SetParametersResult(successful=True)

    return validate


def reject_unknown_overrides(node: Node, *tables: tuple[Param, ...], settings_of: str = '') -> None:
    """Refuse parameters given for this node that it does not declare (a typo in a params file).

    rclpy would otherwise ignore them silently and the run would use a default. ``settings_of``: the
    node whose section holds this one's settings in the shipped files (the actor's and the trainer's
    are in learner:, which actors.launch.py hands to them).
    """
    known = {p.name for table in tables for p in table} | set(BUILT_IN)
    # rclpy keeps the overrides from params files and -p arguments here; there is no public accessor.
    unknown = sorted(set(getattr(node, '_parameter_overrides', {})) - known)
    if unknown:
        raise ValueError(
            f"unknown parameter(s) for node '{node.get_name()}': {', '.join(unknown)}; "
            f'known: {", ".join(sorted(known))}'
        )
    warn_unapplied_sections(node, settings_of=settings_of)  # a section rcl did not apply: nothing to refuse


def warn_unapplied_sections(node: Node, argv=None, settings_of: str = '') -> str:
    """A warning when a params file on the command line has sections named for this node and none
    of them reaches it: `learner:` is /learner, so `ros2 run ... --params-file pendulum.yaml -r
    __ns:=/robot1` set none of the file's learner keys, without a word (the run went on with the
    defaults: lock-step, budget 30, a 0.3 s wait for a person). A trainer or actor given a file with a
    learner: section (``settings_of``) and none of its own is told so too: rcl gives it to /learner
    only, and the trainer ran on Table 1's defaults. Returns the line ('' when none)."""
    from ..files.yaml_files import load_mapping

    argv = sys.argv if argv is None else argv
    ros_args = argv[argv.index('--ros-args') :] if '--ros-args' in argv else []
    files = [ros_args[i + 1] for i, word in enumerate(ros_args[:-1]) if word == '--params-file']
    full, name = node.get_fully_qualified_name(), node.get_name()
    for path in files:
        try:
            data = flat_sections(load_mapping(path, 'params file'))
        except (OSError, ValueError):
            continue  # rcl read it already; what it could not read, it refused
        last = {str(key): str(key).rstrip('/').split('/')[-1] for key in data}
        own = [key for key, token in last.items() if token == name]
        theirs = [key for key, token in last.items() if settings_of and token == settings_of != name]
        if any(section_applies(key, full) for key in own) or not (own or theirs):
            continue
        if own:
            line = (
                f"params file {path}: its section {', '.join(own)} is not this node's ({full}), so none of "
                f'its keys is set here: a section without a leading slash is in the root namespace; write '
                f'/**/{name}: (any namespace) or {full}:'
            )
        else:
            line = (
                f'params file {path}: its section {", ".join(theirs)} is for a node named {settings_of}, so none '
                f'of its keys is set on this {name}: ros2 launch eqhrl_ros actors.launch.py params_file:={path} '
                f'gives them to the trainer and the actors (or write a /**/{name}: section)'
            )
        node.get_logger().warn(line)
        return line
    return ''
