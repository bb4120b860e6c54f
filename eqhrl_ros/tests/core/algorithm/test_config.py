"""LearnerConfig's fields are the one declaration of the learner's hyperparameters."""

import dataclasses

import pytest
import yaml

from eqhrl_ros.core.algorithm.config import CONFIG_FIELDS, LearnerConfig, check_value, ros_name
from eqhrl_ros.parameters import LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS, check_section

from ros_helpers import PARAMS_DIR


def test_the_ros_parameters_are_the_config_fields():
    assert [p.name for p in LEARNER_CONFIG_PARAMS] == [ros_name(f) for f in dataclasses.fields(LearnerConfig)]
    for param in LEARNER_CONFIG_PARAMS:
        f = next(f for f in dataclasses.fields(LearnerConfig) if ros_name(f) == param.name)
        assert param.description == f.metadata['description'] and param.range == f.metadata['range']
        default = LearnerConfig().to_dict()[f.name]
        # An empty list is declared typed and unset (rclpy would type [] as bytes).
        assert param.default == default or (param.kind == 'integer_array' and param.default is None and default == [])


@pytest.mark.parametrize('name', [n for n, f in CONFIG_FIELDS.items() if f.metadata['range'] and f.default != ()])
def test_a_value_outside_the_declared_range_is_refused_by_the_config(name):
    low, high = CONFIG_FIELDS[name].metadata['range']
    kind = type(CONFIG_FIELDS[name].default)
    check_value(name, kind(low))
    check_value(name, kind(high))
    above = high * 2 if high > 0 else 1
    with pytest.raises(ValueError, match=f'LearnerConfig.{name} must be in'):
        LearnerConfig(**{name: kind(above)})


def test_types_follow_the_defaults():
    assert LearnerConfig(actor_lr=1).actor_lr == 1.0 and isinstance(LearnerConfig(actor_lr=1).actor_lr, float)
    with pytest.raises(ValueError, match='must be an integer'):
        LearnerConfig(batch_size=64.0)
    with pytest.raises(ValueError, match='true or false'):
        LearnerConfig(actor_on_advice=1)
    with pytest.raises(ValueError, match='one of'):
        LearnerConfig(threshold_kind='adaptive')


@pytest.mark.parametrize('path', sorted(PARAMS_DIR.glob('*.yaml')), ids=lambda p: p.stem)
def test_each_params_file_fits_the_declarations(path):
    learner = yaml.safe_load(path.read_text())['learner']['ros__parameters']
    check_section('learner', learner, LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS)
    LearnerConfig.from_params(learner, node_keys=[p.name for p in LEARNER_NODE_PARAMS])


def test_a_refused_field_is_named_as_its_ros_parameter_too():
    """From outside: `-p hidden_sizes:=[0]` was refused as `LearnerConfig.hidden`, a name the user
    never gave, and `-p hidden_sizes:=[]` (rclpy leaves an empty array unset) as `got None`."""
    with pytest.raises(
        ValueError, match=r'^LearnerConfig.hidden \(ROS parameter hidden_sizes\) must be positive layer'
    ):
        LearnerConfig.from_params({'hidden_sizes': [0]})
    with pytest.raises(ValueError, match=r'hidden_sizes\) must be a list of layer sizes, got nothing \(an empty list'):
        LearnerConfig.from_params({'hidden_sizes': None})
    with pytest.raises(ValueError, match=r'^LearnerConfig.gamma must be in'):  # the same name: said once
        LearnerConfig(gamma=2.0)


def test_from_params_refuses_unknown_keys():
    with pytest.raises(ValueError, match='unknown learner parameter.*gama'):
        LearnerConfig.from_params({'gama': 0.9})
    assert LearnerConfig.from_params({'hidden_sizes': [8, 8], 'env_id': 'X'}, node_keys=['env_id']).hidden == (8, 8)


def test_the_on_set_callback_refuses_a_parameter_without_a_name():
    from rclpy.parameter import Parameter

    from eqhrl_ros.nodes.params import choices_validator
    from eqhrl_ros.parameters import LEARNER_CONFIG_PARAMS

    validate = choices_validator(LEARNER_CONFIG_PARAMS)
    assert not validate([Parameter('', value=5)]).successful
    assert not validate([Parameter(' ', value=5)]).successful
    assert validate([Parameter('advising_budget', value=5)]).successful
    assert not validate([Parameter('mode', value='nope')]).successful


def test_the_learner_trainer_and_checkpoints_load_without_gymnasium():
    """ActionScaler lives in env_spec.py: a learner, a trainer or a policy expert needs no gym."""
    import subprocess
    import sys

    probe = 'import sys, eqhrl_ros.core.algorithm.learner, eqhrl_ros.core.runs.trainer\n'
    probe += 'import eqhrl_ros.core.runs.checkpoint\n'
    probe += "print(sorted(m for m in sys.modules if m.split('.')[0] in ('gymnasium', 'rclpy')))"
    done = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == '[]'


def test_every_mode_has_a_label_and_a_colour():
    from eqhrl_ros.core.algorithm.config import MODE_COLORS, MODE_LABELS, MODES

    assert set(MODE_LABELS) == set(MODES) == set(MODE_COLORS)
    assert len(set(MODE_COLORS.values())) == len(MODES)


def test_a_random_mode_that_can_never_ask_is_said_to_be_sac():
    """From outside: `ros2 launch eqhrl_ros train.launch.py mode:=random` (the README's advice for a
    person) on a shipped params file, whose random_ask_rate is 0, asked nothing, unsaid."""
    assert LearnerConfig(mode='random').never_asks().startswith('mode random with random_ask_rate 0')
    assert LearnerConfig(mode='ask_random').never_asks().endswith('asks nothing: this run is SAC')
    for asks in (
        LearnerConfig(mode='random', random_ask_rate=0.05),
        LearnerConfig(mode='random', random_ask_schedule=(2, 0)),
        LearnerConfig(mode='ask_random', random_ask_rate=0.5),
        LearnerConfig(mode='eqsac'),
        LearnerConfig(mode='sac'),  # asks nothing by its nature: nothing to say
    ):
        assert asks.never_asks() == '', asks.mode
