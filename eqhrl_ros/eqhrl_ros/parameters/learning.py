"""The parameter tables of the learning nodes: learner, actor and trainer."""

from __future__ import annotations

from ..core.algorithm.config import INT_MAX
from .tables import (
    ACTING_PARAMS,
    ENV_PARAMS,
    KEY_FILE,
    LEARNER_CONFIG_PARAMS,
    STEP_LIMIT_PARAMS,
    TORCH_THREADS,
    Param,
)


def run_params(output_dir: str) -> tuple:
    """A learning run's folder, saves and end (the learner and the trainer nodes)."""
    return (
        Param('output_dir', output_dir, 'Folder for episodes.csv, checkpoints and the exported policy', path=True),
        Param(
            'checkpoint_every_episodes', 10, 'Save a checkpoint every N episodes (0: only on shutdown)', (0, INT_MAX)
        ),
        Param('save_replay', False, 'Also save the replay memories with each checkpoint (large)'),
        Param('resume', False, 'Resume from output_dir/checkpoint.pt at start-up'),
        Param(
            'overwrite',
            False,
            'Replace a run already in output_dir (episodes.csv, checkpoint, replay, policy), removed once the '
            'start is accepted (a start refused before, e.g. for its prior, keeps it); without it (or resume) such '
            'a folder is refused, and so is the two together',
        ),
        Param(
            'max_episodes',
            0,
            "Stop after this many episodes (0: never): the learner stops acting and learning; a trainer's actors "
            'stop acting, and the trainer makes the updates it still owes, then stops',
            (0, INT_MAX),
        ),
        Param('shutdown_when_done', False, 'Shut the process down once max_episodes is reached'),
        Param(
            'record',
            False,
            'Write output_dir/record.mcap (record-N.mcap on each resume): what the node sends and receives, '
            'the advise calls, every gate decision and the transitions it stored (see README, "The record")',
        ),
    )


# The camera a learner or an actor reads beside the observation vector (nodes/camera_input.py).
CAMERA_PARAMS = (
    Param(
        'camera',
        '',
        "Learn from this camera of the env's env_info beside the observation vector (its name there); "
        'the learner then waits for env_info. Empty: the vector alone',
    ),
    Param(
        'camera_publisher',
        '',
        "The node whose frames to take (full name); empty: any one node. While two nodes publish the camera's "
        'topic, no frame is taken (a stranger could show the learner anything)',
    ),
    Param(
        'camera_transport',
        'raw',
        "How the camera's frames come: raw (sensor_msgs/Image on its topic) or compressed "
        '(sensor_msgs/CompressedImage, JPEG or PNG, on <topic>/compressed, as image_transport names it)',
        choices=('raw', 'compressed'),
    ),
    Param('camera_stack', 3, 'Frames the learner reads at once: the newest and those before it', (1, 16)),
    Param(
        'camera_wait_s',
        0.5,
        "Longest an observation waits for the step's frame; then the newest frame there is stands in "
        '(counted as stale), or, with none yet, the observation is dropped',
        (0.0, 60.0),
    ),
)

LEARNER_NODE_PARAMS = (
    *ACTING_PARAMS,
    *CAMERA_PARAMS,
    *run_params('runs/learner'),
    TORCH_THREADS,
    Param(
        'prior',
        None,
        'Records of earlier runs (run folders or .mcap files) whose advised and person-initiated transitions '
        'go into D and D_advising before the first step (a fresh start only; spaces must match)',
        kind='string_array',
        path=True,
    ),
)

# policy_driver (nodes/policy_driver_node.py): a trained policy drives the env, learning nothing.
POLICY_DRIVER_PARAMS = (
    *ENV_PARAMS,
    Param(
        'policy_path',
        '',
        "The policy file a learner or trainer exported (its run folder's policy.pt); required",
        path=True,
    ),
    Param(
        'max_episodes',
        0,
        'Drive this many episodes, then stop (0: never): the node says their mean return and exits 0',
        (0, INT_MAX),
    ),
)

ACTOR_NODE_PARAMS = (
    *ACTING_PARAMS,
    *CAMERA_PARAMS,
    Param('actor_name', '', "This actor's name in the trainer's record and log (empty: the node's full name)"),
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
    *STEP_LIMIT_PARAMS,
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
