"""Every node's parameters, one table per node, with defaults, descriptions, ranges and choices.

tables.py          Param; the tables derived from the core (LearnerConfig, HumanLimits); the
                   parameters every node takes; --help text; a params file's sections checked
learning.py        the learner's, the actor's and the trainer's own tables
env_and_people.py  gym_env's, expert's, teleop_expert's, keyboard_teleop's and advice_console's

Each table lives in its module; this package names them all in one place, for the nodes, the
command-line programs, the launch files and the README's tables (tools/update_param_tables.py).
"""

from .env_and_people import (
    CONSOLE_PARAMS,
    EXPERT_PARAMS,
    GYM_ENV_PARAMS,
    KEY_STEP,
    KEYBOARD_PARAMS,
    TELEOP_EXPERT_PARAMS,
)
from .learning import (
    ACTOR_NODE_PARAMS,
    LEARNER_NODE_PARAMS,
    POLICY_DRIVER_PARAMS,
    TRAINER_PARAMS,
    learner_section_for,
    run_params,
)
from .tables import (
    ACTING_PARAMS,
    BUILT_IN,
    ENV_PARAMS,
    HUMAN_LIMIT_PARAMS,
    KEY_FILE,
    LEARNER_CONFIG_PARAMS,
    SHARED_PARAM_NAMES,
    SPACE_PARAMS,
    TORCH_THREADS,
    Param,
    check_section,
    default_of,
    describe,
    file_section,
    flat_sections,
    params_of,
    section_applies,
)

__all__ = [
    'ACTING_PARAMS',
    'ACTOR_NODE_PARAMS',
    'BUILT_IN',
    'CONSOLE_PARAMS',
    'ENV_PARAMS',
    'EXPERT_PARAMS',
    'GYM_ENV_PARAMS',
    'HUMAN_LIMIT_PARAMS',
    'KEYBOARD_PARAMS',
    'KEY_FILE',
    'KEY_STEP',
    'LEARNER_CONFIG_PARAMS',
    'LEARNER_NODE_PARAMS',
    'POLICY_DRIVER_PARAMS',
    'SHARED_PARAM_NAMES',
    'SPACE_PARAMS',
    'TELEOP_EXPERT_PARAMS',
    'TORCH_THREADS',
    'TRAINER_PARAMS',
    'Param',
    'check_section',
    'default_of',
    'describe',
    'file_section',
    'flat_sections',
    'section_applies',
    'learner_section_for',
    'params_of',
    'run_params',
]
