"""The parameter tables of the env node, the expert node and the person's nodes (teleop_expert,
keyboard_teleop, advice_console)."""

from __future__ import annotations

from ..core.algorithm.config import INT_MAX
from ..core.data import camera_frames
from ..core.experts.factory import EXPERT_BACKENDS
from ..core.experts.teleop import ANSWER_MODES
from .tables import ENV_PARAMS, HUMAN_LIMIT_PARAMS, KEY_FILE, SPACE_PARAMS, Param

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
        'camera',
        '',
        "A camera to publish and announce in env_info under this name: the env's rendering, resized to "
        "camera_height x camera_width, on <camera>/image_raw (sensor_msgs/Image) before each step's observation "
        '(empty: none)',
    ),
    Param('camera_height', 84, "The camera's frame height in pixels", (15, 4096)),
    Param('camera_width', 84, "The camera's frame width in pixels", (15, 4096)),
    Param('camera_encoding', 'rgb8', "The camera's encoding: colour or grey", choices=('rgb8', 'mono8')),
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
    Param('policy_path', '', 'Policy file exported by a learner (backend policy)', path=True),
    Param(
        'response_delay_s',
        0.0,
        'Artificial delay before answering (to rehearse a slow expert)',
        (0.0, 600.0),
        dynamic=True,
    ),
    Param('enabled', True, 'Answer with advice; when false, decline every request', dynamic=True),
    KEY_FILE,  # only requests signed with it are answered, and the answers are signed
    *HUMAN_LIMIT_PARAMS,
    Param('seed', 0, 'Seed of the simulated person (backend simulated_human)', (0, INT_MAX)),
)


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
        '(env units, any dimension) answers it, once it holds still (answer_settle_s)',
        (0.0, 1e6),
        dynamic=True,
    ),
    Param(
        'answer_settle_s',
        0.3,
        'Window mode: a command steered with the deadman held answers once it has held still this long '
        '(the answer is where the person stopped, not their first key step); 0: the first change answers',
        (0.0, 60.0),
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
    Param(
        'token',
        '',
        'Secret the page address must carry (?token=...); a token or token_file is required when host is not '
        'localhost. Any node on the graph can read this parameter (ros2 param get): prefer token_file',
    ),
    Param(
        'token_file',
        '',
        'A file holding the secret the page address must carry (?token=<its content>; made like key_file), '
        'which, unlike token, no node on the graph can read',
        path=True,
    ),
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
    Param(
        'image_topic',
        'gym_env/image',
        f'sensor_msgs/Image topic with the env frames ({", ".join(camera_frames.ENCODINGS)}; others are not shown)',
    ),
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
