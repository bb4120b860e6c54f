"""The machinery of the parameter tables: Param, the tables derived from the core's dataclasses,
the parameters every node takes, and checking a params file's sections as the nodes would.

No ROS here: the nodes declare these through nodes/params.py (rclpy checks each value against
its descriptor), while the command-line programs, the launch files and --help read them without
starting ROS (eqhrl-experiment checks a params file's sections with check_section).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Optional

from ..core.algorithm.config import INT_MAX, LearnerConfig, ros_name
from ..core.data.transitions import StepLimits
from ..core.experts.simulated_human import HumanLimits


@dataclass(frozen=True)
class Param:
    name: str
    default: Any
    description: str
    range: Optional[tuple] = None  # (low, high) for numbers, inclusive
    choices: Optional[tuple] = None  # allowed strings
    dynamic: bool = False  # may change while the node runs
    # For a parameter with no default (default None): its type, e.g. 'double_array'. It is
    # declared only when a params file or -p gives it (nodes/params.py says why); its value is
    # None until then.
    kind: Optional[str] = None
    # A file or folder (or a list of them): a leading ~ is the home of the user the node runs as.
    # ROS does not expand it, nor does a shell inside `-p output_dir:=~/runs` (before, that made a
    # folder named ~ in the working directory).
    path: bool = False


def params_of(declared) -> tuple[Param, ...]:
    """ROS parameters for the fields of a dataclass declared with core.algorithm.config.hyper()."""

    def param(f):
        if f.default == ():  # an empty list would be typed as bytes: declared typed and unset
            return Param(
                ros_name(f),
                None,
                f.metadata['description'],
                f.metadata['range'],
                kind='integer_array',
                dynamic=f.metadata['dynamic'],
            )
        return Param(
            ros_name(f),
            list(f.default) if isinstance(f.default, tuple) else f.default,
            f.metadata['description'],
            f.metadata['range'],
            f.metadata['choices'],
            f.metadata['dynamic'],
        )

    return tuple(param(f) for f in dataclasses.fields(declared))


# Parameters of the learner that map one-to-one onto core.LearnerConfig fields: derived
# from the fields' declarations (core/algorithm/config.py), never written here.
LEARNER_CONFIG_PARAMS = params_of(LearnerConfig)
# The simulated person's limits (expert backend simulated_human): core/experts/simulated_human.py.
HUMAN_LIMIT_PARAMS = params_of(HumanLimits)

# The env's spaces, for an env node that publishes no env_info. Every node accepts them, so
# that a params file's shared `/**:` section can set them for all nodes at once.
SPACE_PARAMS = (
    Param(
        'observation_size',
        0,
        'Observation size, for an env node that publishes no env_info (0: from env_id or env_info); '
        'with action_low and action_high',
        (0, INT_MAX),
    ),
    Param(
        'action_low',
        None,
        'Action lower bounds in env units, one per dimension (unset: from env_id or env_info)',
        kind='double_array',
    ),
    Param(
        'action_high',
        None,
        'Action upper bounds in env units, one per dimension (unset: from env_id or env_info)',
        kind='double_array',
    ),
)
# env_id and the spaces: what every node but gym_env accepts about the env.
ENV_PARAMS = (
    Param(
        'env_id',
        '',
        'Gymnasium env id, a shortcut for its spaces and success rule (empty: from env_info, or the spaces '
        'given as parameters)',
    ),
    *SPACE_PARAMS,
    Param(
        'env_node',
        '',
        'The node whose env_info to take (full name); empty: the node publishing observation. An env_info '
        'while another node publishes it too is held, not obeyed. A learner or actor takes observations only '
        'while one node publishes them (this one, when set)',
    ),
)
# What a params file's shared `/**:` section may set: every node accepts these.
SHARED_PARAM_NAMES = ('env_id', *(p.name for p in SPACE_PARAMS), 'use_sim_time')

KEY_FILE = Param(
    'key_file',
    '',
    "A file holding this deployment's shared secret: what this node sends is signed with it, and what it "
    'receives unsigned or signed otherwise is refused (HMAC-SHA256; integrity, no secrecy). Empty: no key',
    path=True,
)
# What an env step may hold (core/data/transitions.py StepLimits): the learner and actors drop a
# step beyond them, the trainer refuses a batch holding one.
STEP_LIMIT_PARAMS = (
    Param(
        'max_abs_observation',
        StepLimits.max_abs_observation,
        'An observation value of larger magnitude cannot come from the env: the learner and actors drop its step, '
        'the trainer refuses a batch holding one',
        (1e-6, 1e30),
    ),
    Param(
        'max_abs_reward',
        StepLimits.max_abs_reward,
        'A reward of larger magnitude is refused likewise (raise it for an env of larger rewards)',
        (1e-6, 1e30),
    ),
)
# What the learner and the actor nodes share: acting and asking for advice (nodes/acting.py).
ACTING_PARAMS = (
    *ENV_PARAMS,
    Param('advice_enabled', True, 'Ask the expert when the gates fire (off: the gates are only logged)', dynamic=True),
    Param('advice_timeout_s', 0.5, 'Seconds to wait for the expert before acting alone', (0.001, 600.0), dynamic=True),
    Param('accept_expert', '', 'Accept advice only from this expert name (empty: any)', dynamic=True),
    KEY_FILE,  # advise requests signed, and only answers signed for them taken
    *STEP_LIMIT_PARAMS,
    Param(
        'expert_wait_s',
        10.0,
        "While advice is open and asks for one answer, the env's first observation waits up to this long "
        "for a node to serve 'advise' (nodes started together find each other over seconds); 0: act at once",
        (0.0, 600.0),
        dynamic=True,
    ),
    Param(
        'stall_timeout_s',
        5.0,
        'Warn when no observation came for this long mid-episode (the env paused, '
        'died or is starved); the episode continues if its next step comes',
        (0.1, 86400.0),
        dynamic=True,
    ),
    Param('publish_gate_debug', False, 'Publish every gate decision on ~/gate_debug', dynamic=True),
    Param(
        'person_publisher',
        '',
        "The node whose person_command to take (full name); empty: teleop_expert in this node's namespace. "
        'While another node publishes person_command too, no command is taken (a stranger could drive)',
    ),
)
TORCH_THREADS = Param(
    'torch_threads',
    0,
    "torch intra-op threads; 0: torch's default count while the machine's cores are free, 1 while another "
    'process keeps them busy (core/algorithm/cpu_threads.py)',
    (0, 256),
)


def describe(*tables: tuple[Param, ...]) -> str:
    """The parameters of a node as help text: name, default, range or choices, description."""
    lines = []
    for param in (p for table in tables for p in table):
        bounds = ''
        if param.range is not None:
            bounds = (
                f' [{param.range[0]:g}, {param.range[1]:g}]'
                if isinstance(param.default, float)
                else f' [{param.range[0]}, {param.range[1]}]'
            )
        elif param.choices:
            bounds = f' ({"|".join(param.choices)})'
        default = (
            '(unset)'
            if param.default is None
            else repr(param.default)
            if isinstance(param.default, str)
            else str(param.default).lower()
            if isinstance(param.default, bool)
            else str(param.default)
        )
        lines.append(f'  {param.name}{" *" if param.dynamic else ""} = {default}{bounds}')
        lines.append(f'      {param.description}')
    return '\n'.join(lines)


# Parameters every rclpy node declares itself.
BUILT_IN = ('use_sim_time', 'start_type_description_service')


def check_section(node_name: str, values: dict, *tables: tuple[Param, ...]) -> None:
    """Refuse a params-file section as the node would at start-up: an unknown name, a value
    of another type than the default's, out of range or outside the choices. For readers of
    a params file that start no node (eqhrl-experiment's in-process runs)."""
    by_name = {p.name: p for table in tables for p in table}
    unknown = sorted(set(values) - set(by_name) - set(BUILT_IN))
    if unknown:
        raise ValueError(
            f"unknown parameter(s) for node '{node_name}': {', '.join(unknown)}; known: {', '.join(sorted(by_name))}"
        )
    for name, value in values.items():
        param = by_name.get(name)
        if param is None:
            continue
        if param.kind == 'double_array':
            if not (
                isinstance(value, list)
                and value
                and all(isinstance(v, float) or (isinstance(v, int) and not isinstance(v, bool)) for v in value)
            ):
                raise ValueError(f"parameter '{name}' of node '{node_name}' is {value!r}; expected a list of numbers")
            continue
        if param.kind == 'integer_array':
            if not (isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
                raise ValueError(f"parameter '{name}' of node '{node_name}' is {value!r}; expected a list of integers")
            continue
        if param.kind == 'string_array':
            if not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
                raise ValueError(f"parameter '{name}' of node '{node_name}' is {value!r}; expected a list of strings")
            continue
        kind = type(param.default)
        same = (
            isinstance(value, kind) and not (kind is int and isinstance(value, bool))
            if kind is not list
            else isinstance(value, list)
        )
        if not same:
            raise ValueError(
                f"parameter '{name}' of node '{node_name}' is {value!r}; expected a "
                f'{kind.__name__} like {param.default!r}'
            )
        if param.range is not None and not param.range[0] <= value <= param.range[1]:
            raise ValueError(
                f"parameter '{name}' of node '{node_name}' is {value!r}; expected [{param.range[0]}, {param.range[1]}]"
            )
        if param.choices and value not in param.choices:
            raise ValueError(f"parameter '{name}' of node '{node_name}' is {value!r}; expected one of {param.choices}")


def section_applies(key: str, node: str) -> bool:
    """Whether rcl gives the params file section ``key`` to the node of full name ``node``
    (e.g. /robot1/learner): a key without a leading slash is rooted (`learner` is /learner, which a
    node in a namespace is not), `*` matches one name and `**` any number, none included
    (`/**/learner` is every node named learner)."""
    want = [t for t in ('/' + key.lstrip('/')).split('/') if t]
    have = [t for t in node.split('/') if t]

    def match(i: int, j: int) -> bool:
        if i == len(want):
            return j == len(have)
        if want[i] == '**':
            return any(match(i + 1, k) for k in range(j, len(have) + 1))
        return j < len(have) and want[i] in ('*', have[j]) and match(i + 1, j + 1)

    return match(0, 0)


def flat_sections(data: dict) -> dict:
    """A parsed params file with each section under its full key, in the file's order: rcl also
    reads the nested form, a namespace holding its nodes (`robot1: {learner: {ros__parameters:
    …}}` is `robot1/learner`). Before, the package's readers saw no section there, and the launch
    files (which pass each node its sections) ran such a file's nodes on their defaults."""
    flat: dict = {}

    def walk(prefix: str, mapping: dict) -> None:
        for key, value in mapping.items():
            name = f'{prefix.rstrip("/")}/{str(key).strip("/")}' if prefix else str(key)
            nested = isinstance(value, dict) and value and 'ros__parameters' not in value
            if nested and all(isinstance(v, dict) for v in value.values()):
                walk(name, value)
            else:
                flat[name] = value

    walk('', data)
    return flat


def file_section(data: dict, node_name: str, namespace: str = '') -> dict:
    """A node's parameters from a parsed params file, as rcl gives them to the node: its own
    section and the shared `/**` section, applied in the order they appear in the file (a key
    in both takes the value of the later one). With ``namespace`` (a launch file's nodes in a
    namespace another launch file pushed), the node is ``namespace``/``node_name`` and a bare
    `node_name:` section is its own too: the file was given for the nodes the launch starts."""
    data = flat_sections(data)

    def values(key):
        section = data.get(key) or {}
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params or {}, dict):
            raise ValueError(f"params file section '{key}' must hold a ros__parameters mapping")
        return dict(params or {})

    unknown = sorted(set(values('/**')) - set(SHARED_PARAM_NAMES))
    if unknown:
        raise ValueError(
            f"the shared '/**' section holds {', '.join(unknown)}, which not every node accepts; "
            f"shared keys: {', '.join(SHARED_PARAM_NAMES)} (put the others in the node's own section)"
        )
    ns, name = namespace.strip('/'), node_name.strip('/')
    full = f'/{ns}/{name}' if ns else f'/{name}'
    merged = {}
    for key in data:  # the file's order (yaml keeps it)
        if section_applies(str(key), full) or str(key) == node_name:
            merged.update(values(key))
    return merged


def default_of(table: tuple[Param, ...], name: str) -> Any:
    """The default of parameter ``name`` in ``table`` (KeyError if it has none there)."""
    for param in table:
        if param.name == name:
            return param.default
    raise KeyError(f'no parameter {name!r} in this table')
