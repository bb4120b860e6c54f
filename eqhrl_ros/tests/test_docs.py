"""The package README documents every declared parameter and every topic field."""

from pathlib import Path

import pytest

from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.params import (
    EXPERT_PARAMS,
    GYM_ENV_PARAMS,
    KEYBOARD_PARAMS,
    LEARNER_CONFIG_PARAMS,
    LEARNER_NODE_PARAMS,
    TELEOP_EXPERT_PARAMS,
)

README = (Path(__file__).resolve().parents[1] / 'README.md').read_text()


@pytest.mark.parametrize(
    'param',
    [
        *GYM_ENV_PARAMS,
        *EXPERT_PARAMS,
        *LEARNER_CONFIG_PARAMS,
        *LEARNER_NODE_PARAMS,
        *TELEOP_EXPERT_PARAMS,
        *KEYBOARD_PARAMS,
    ],
    ids=lambda p: p.name,
)
def test_parameter_is_in_the_readme_table(param):
    assert f'| `{param.name}` |' in README


def test_message_fields_are_documented():
    for field in (*messages.OBS_TAIL, *messages.STATS_FIELDS, *messages.GATE_FIELDS, *messages.ADVICE_REQUEST_TAIL):
        assert f'`{field}`' in README, field
