"""Every node's parameters, one table per node, with defaults, descriptions, ranges and choices.

No ROS here: the nodes declare these through nodes/params.py (rclpy checks each value against
its descriptor), while the command-line programs, the launch files and --help read them without
starting ROS (eqhrl-experiment checks a params file's sections with check_section).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Optional

from .core.algorithm.config import INT_MAX, LearnerConfig, ros_name
from .core.experts.factory import EXPERT_BACKENDS
from .core.experts.simulated_human import HumanLimits
from .core.experts.teleop import ANSWER_MODES


@dataclass(frozen=True)
class Param:
    name: str
    default: Any
    description: str
    range: Optional[tuple] = None  # (low, high) for numbers, inclusive
    choices: Optional[tuple] = None  # allowed strings
    dynamic: bool = False  # may change while the node runs
    # For a parameter with no default (default None): its type, e.g. 'double_array'. rclpy
    # declares it typed and unset (an empty list would be typed as bytes); its value is None
    # until a params file or -p sets it.
    kind: Optional[str] = None


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
        'while another node publishes it too is held, not obeyed',
    ),
)
# What a params file's shared `/**:` section may set: every node accepts these.
SHARED_PARAM_NAMES = ('env_id', *(p.name for p in SPACE_PARAMS), 'use_sim_time')

# What the learner and the actor nodes share: acting and asking for advice (nodes/acting.py).
ACTING_PARAMS = (
    *ENV_PARAMS,
    Param('advice_enabled', True, 'Ask the expert when the gates fire (off: the gates are only logged)', dynamic=True),
    Param('advice_timeout_s', 0.5, 'Seconds to wait for the expert before acting alone', (0.001, 600.0), dynamic=True),
    Param('accept_expert', '', 'Accept advice only from this expert name (empty: any)', dynamic=True),
    Param(
        'stall_timeout_s',
        5.0,
        'Warn when no observation came for this long mid-episode (the env paused, '
        'died or is starved); the episode continues if its next step comes',
        (0.1, 86400.0),
        dynamic=True,
    ),
    Param('publish_gate_debug', False, 'Publish every gate decision on ~/gate_debug', dynamic=True),
)
TORCH_THREADS = Param('torch_threads', 0, 'torch intra-op threads (0: torch default)', (0, 256))
KEY_FILE = Param(
    'key_file',
    '',
    "A file holding this deployment's shared secret: what this node sends is signed with it, and what it "
    'receives unsigned or signed otherwise is refused (HMAC-SHA256; integrity, no secrecy). Empty: no key',
)


def run_params(output_dir: str) -> tuple:
    """A learning run's folder, saves and end (the learner and the trainer nodes)."""
    return (
        Param('output_dir', output_dir, 'Folder for episodes.csv, checkpoints and the exported policy'),
        Param(
            'checkpoint_every_episodes', 10, 'Save a checkpoint every N episodes (0: only on shutdown)', (0, INT_MAX)
        ),
        Param('save_replay', False, 'Also save the replay memories with each checkpoint (large)'),
        Param('resume', False, 'Resume from output_dir/checkpoint.pt at start-up'),
        Param(
            'overwrite',
            False,
            'Replace a run already in output_dir (episodes.csv, checkpoint, replay, policy); '
            'without it (or resume) such a folder is refused',
        ),
        Param('max_episodes', 0, 'Stop learning after this many episodes (0: never)', (0, INT_MAX)),
        Param('shutdown_when_done', False, 'Shut the process down once max_episodes is reached'),
        Param(
            'record',
            False,
            'Write output_dir/record.mcap (record-N.mcap on each resume): what the node sends and receives, '
            'the advise calls, every gate decision and the transitions it stored (see README, "The record")',
        ),
    )


LEARNER_NODE_PARAMS = (
    *ACTING_PARAMS,
    *run_params('runs/learner'),
    TORCH_THREADS,
    Param(
        'prior',
        None,
        'Records of earlier runs (run folders or .mcap files) whose advised and person-initiated transitions '
        'go into D and D_advising before the first step (a fresh start only; spaces must match)',
        kind='string_array',
    ),
)

ACTOR_NODE_PARAMS = (
    *ACTING_PARAMS,
    Param('actor_name', '', "This actor's name in the trainer's record and log (empty: the node's full name)"),
    KEY_FILE,
    Param(
        'trainer_id',
        '',
        'The trainer whose weights to act with (its id, as it logs it); empty: the first one joined. Another '
        'trainer is followed only when it publishes alone (the one followed left), or when this is set to it',
        dynamic=True,
    ),
    Param(
        'batch_transitions',
        50,
        'Send transitions to the trainer in batches of this many (an episode end or flush_period_s sends sooner)',
        (1, 100_000),
    ),
    Param('flush_period_s', 0.5, 'Send a batch at most this long after its first transition', (0.001, 3600.0)),
    Param(
        'weights_wait_steps',
        0,
        'Lock-step simulators: after this many steps on the same weights, wait for newer ones before acting, '
        'once the trainer updates and while it listens (0: never wait); bounds how far actors run ahead of learning',
        (0, INT_MAX),
    ),
    Param(
        'outbox_limit',
        100_000,
        "Transitions kept until the trainer's checkpoint holds them (also while no trainer listens); past it "
        'the oldest batch goes, counted as lost when the trainer never had it',
        (1, INT_MAX),
    ),
    Param(
        'exit_wait_s',
        6.0,
        'At exit (Ctrl-C, SIGTERM): wait up to this long for the trainer to store every transition sent '
        '(0: do not wait); what it still lacks then is counted lost in the exit line. ros2 launch kills a node '
        '10 s after its Ctrl-C',
        (0.0, 60.0),
    ),
    TORCH_THREADS,
)

TRAINER_PARAMS = (
    *ENV_PARAMS,
    *run_params('runs/trainer'),
    Param(
        'exit_wait_s',
        4.0,
        'At exit: keep storing what actors still send for up to this long, until none publishes (their own '
        'exit_wait_s waits for this), then save (0: save at once)',
        (0.0, 60.0),
    ),
    Param(
        'updates_per_transition',
        1.0,
        'Gradient updates per transition received once D holds learning_starts (the lock-step '
        "learner's updates_per_step)",
        (0.01, 100.0),
    ),
    Param('weights_every_updates', 50, 'Publish the networks on weights every N updates', (1, INT_MAX)),
    Param(
        'weights_on_wire',
        'float32',
        'How the tensors travel on weights: float32, or float16 (half the bytes, for a thin link; the trainer '
        'learns in float32, the actors cast back)',
        choices=('float32', 'float16'),
    ),
    Param(
        'actor_silence_s', 10.0, 'Log an actor that sent nothing for this long (it may have stopped)', (0.1, 86400.0)
    ),
    Param('report_period_s', 10.0, 'Log transitions, updates and weights per second this often', (0.1, 86400.0)),
    Param(
        'max_abs_observation',
        1e6,
        'A batch holding an observation of larger magnitude is refused whole (it cannot come from the env)',
        (1e-6, 1e30),
    ),
    Param(
        'max_abs_reward',
        1e4,
        'A batch holding a reward of larger magnitude is refused whole (raise it for an env of larger rewards)',
        (1e-6, 1e30),
    ),
    KEY_FILE,
    Param(
        'actors',
        None,
        'The actor names whose transitions are taken (their node full names, or actor_name); others are '
        'refused and counted. The trainer starts only with this, a key_file, or accept_any_actor',
        kind='string_array',
    ),
    Param(
        'accept_any_actor',
        False,
        'Take transitions from any actor name that sends well-formed batches, with neither actors nor '
        'key_file (a closed, trusted network only: anyone on the graph could write into D)',
    ),
    Param(
        'inbox_limit_mb',
        256.0,
        'Batches received and not stored yet are held up to this size; past it a batch is dropped and counted',
        (1.0, 1e6),
    ),
    TORCH_THREADS,
)


def learner_section_for(section: dict, node_params: tuple) -> dict:
    """The keys of a params file's ``learner:`` section that an actor or a trainer takes: the
    algorithm's (the same for all three) and those of its own table. Launch files use it, so
    that one params file configures the lock-step learner and the actor/trainer split alike."""
    names = {p.name for p in (*LEARNER_CONFIG_PARAMS, *node_params)}
    return {key: value for key, value in section.items() if key in names}


GYM_ENV_PARAMS = (
    Param('env_id', 'Pendulum-v1', 'Gymnasium env id (any Box action space)'),
    *SPACE_PARAMS,
    Param('max_episode_steps', 100, 'Steps before truncation (paper: Pendulum 100, LunarLander 600)', (1, INT_MAX)),
    Param('seed', 42, 'Seed of the first reset', (0, INT_MAX)),
    Param(
        'realtime',
        False,
        'Step at rate_hz holding the last action, instead of lock-step on each action; the clock starts '
        'when the first subscriber of observation connects',
    ),
    Param('rate_hz', 20.0, 'Step rate in real-time mode', (0.1, 1000.0)),
    Param(
        'publish_images',
        False,
        'Publish rendered frames on ~/image (sensor_msgs/Image, rgb8) for a person watching in rqt_image_view or rviz',
    ),
    Param('image_rate_hz', 10.0, 'Most frames per second on ~/image', (0.1, 120.0)),
    Param(
        'republish_period_s',
        1.0,
        'Lock-step: re-send the current observation if no action came for this '
        'long (a learner that started late or restarted)',
        (0.01, 3600.0),
    ),
    Param(
        'max_action_change',
        0.0,
        'Most an action may change from the one before, per step and dimension, in env units (0: no limit)',
        (0.0, 1e9),
    ),
)

EXPERT_PARAMS = (
    Param(
        'backend',
        'heuristic',
        'Who answers: a built-in controller or an exported policy file',
        choices=EXPERT_BACKENDS,
    ),
    Param(
        'env_id',
        '',
        "Env name the heuristic controller is for: a gymnasium id or an env node's name, e.g. "
        'double_integrator (empty: the name in env_info)',
    ),
    *SPACE_PARAMS,
    Param('policy_path', '', 'Policy file exported by a learner (backend policy)'),
    Param(
        'response_delay_s',
        0.0,
        'Artificial delay before answering (to rehearse a slow expert)',
        (0.0, 600.0),
        dynamic=True,
    ),
    Param('enabled', True, 'Answer with advice; when false, decline every request', dynamic=True),
    *HUMAN_LIMIT_PARAMS,
    Param('seed', 0, 'Seed of the simulated person (backend simulated_human)', (0, INT_MAX)),
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


def file_section(data: dict, node_name: str) -> dict:
    """A node's parameters from a parsed params file, as rcl gives them to the node: its own
    section and the shared `/**` section, applied in the order they appear in the file (a key
    in both takes the value of the later one)."""

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
    merged = {}
    for key in data:  # the file's order (yaml keeps it)
        if key in ('/**', node_name, f'/{node_name}'):
            merged.update(values(key))
    return merged


TELEOP_EXPERT_PARAMS = (
    *ENV_PARAMS,
    Param('source', 'joy', 'Which teleop input becomes advice', choices=('joy', 'twist', 'array')),
    KEY_FILE,
    Param(
        'command_publisher',
        '',
        "The node the person's commands come from (full name, e.g. /my_driver); empty: for source array, "
        'advice_console or keyboard_teleop (in this namespace), for joy and twist any one node. While another '
        'node publishes on the command topic too, every command is refused',
    ),
    Param(
        'axes',
        [0],
        'joy: joystick axis index for each action dimension (teleop_twist_joy style); '
        'array: command value index for each action dimension',
        dynamic=True,
    ),
    Param(
        'twist_fields',
        ['angular.z'],
        'twist: Twist field for each action dimension, e.g. linear.x, angular.z',
        dynamic=True,
    ),
    Param('scales', [1.0], 'Scale for each action dimension: action = input * scale + offset', dynamic=True),
    Param('offsets', [0.0], 'Offset for each action dimension', dynamic=True),
    Param('require_enable_button', True, 'joy: advise only while the enable (deadman) button is held', dynamic=True),
    Param('enable_button', 0, 'joy: index of the enable (deadman) button', (0, 128), dynamic=True),
    Param('answer_button', 1, 'joy: index of the answer button (-1: none)', (-1, 128), dynamic=True),
    Param('skip_button', 2, 'joy: index of the skip button (-1: none)', (-1, 128), dynamic=True),
    Param(
        'answer_mode',
        'window',
        'window: hold each request open until the person acts (or the window passes); '
        'instant: answer at once with the held command (for a person who steers all along)',
        choices=ANSWER_MODES,
    ),
    Param(
        'answer_window_s',
        5.0,
        "Seconds the person is given per request (window mode); cut to the learner's advice_timeout_s less 0.2 s",
        (0.05, 3600.0),
        dynamic=True,
    ),
    Param(
        'answer_change',
        0.05,
        'Window mode: a command that differs from the one held when the request came by more than this '
        '(env units, any dimension) answers it',
        (0.0, 1e6),
        dynamic=True,
    ),
    Param('stale_after_s', 0.5, 'Decline when the latest command is older than this', (0.01, 3600.0), dynamic=True),
)

# A person's key press: keyboard_teleop's `step` and the page's (advice_console's `step`), one default.
KEY_STEP = Param(
    'step',
    0.25,
    "Change of the command per key press, in [-1, 1] units; a press against the command's sign goes to 0 "
    'first, so full scale reverses in 1 + 1/step presses',
    (0.01, 1.0),
)

KEYBOARD_PARAMS = (
    *ENV_PARAMS,
    Param(
        'dimensions',
        0,
        'Action dimensions to command (Pendulum 1, LunarLander 2; 0: the action size from env_id or env_info, '
        'at most 2)',
        (0, 2),
    ),
    KEY_STEP,
    Param('rate_hz', 10.0, 'Publishing rate of teleop_command', (0.5, 100.0)),
    KEY_FILE,
)

CONSOLE_PARAMS = (
    *ENV_PARAMS,
    KEY_STEP,
    Param(
        'host',
        '127.0.0.1',
        'Address the page is served on: localhost only by default; another address lets other '
        'machines steer the robot and needs a token',
    ),
    Param('port', 8080, 'TCP port of the page (0: any free port, logged at start)', (0, 65535)),
    Param('token', '', 'Secret the page address must carry (?token=...); required when host is not localhost'),
    Param(
        'allowed_hosts',
        None,
        "Names (not addresses) the page may be opened by, besides localhost, this machine's name and host: "
        'a request whose Host header names another is refused (DNS rebinding). IP addresses are always accepted',
        kind='string_array',
    ),
    KEY_FILE,
    Param('max_connections', 128, 'Connections the page server holds at once', (1, 10_000)),
    Param('max_connections_per_client', 64, 'Connections it holds from one client address', (1, 10_000)),
    Param(
        'header_timeout_s',
        10.0,
        'A connection that has not sent a whole request header in this time is closed (idle, half-open)',
        (0.1, 600.0),
    ),
    Param('image_topic', 'gym_env/image', 'sensor_msgs/Image topic with the env frames (rgb8, bgr8 or mono8)'),
    Param('image_rate_hz', 15.0, 'Most frames per second sent to each page', (0.1, 60.0)),
    Param('jpeg_quality', 75, 'JPEG quality of the frames sent to the page', (10, 95)),
    Param('rate_hz', 20.0, 'Publishing rate of teleop_command while a page is open', (1.0, 100.0)),
    Param('learner_node', 'learner', "Node whose advice_enabled and advising_budget the page's controls set"),
    Param(
        'teleop_node',
        'teleop_expert',
        "Node whose answer window and mapping (axes, scales, offsets) the page's countdown and bars follow",
    ),
    Param('require_deadman', True, 'Commands count only while the deadman (Shift, gamepad LB) is held'),
)


def default_of(table: tuple[Param, ...], name: str) -> Any:
    """The default of parameter ``name`` in ``table`` (KeyError if it has none there)."""
    for param in table:
        if param.name == name:
            return param.default
    raise KeyError(f'no parameter {name!r} in this table')
