"""A learner's saved state checked before anything of it is used: the structure and the values
no run of this learner can produce are refused with the key that is wrong."""

from __future__ import annotations

import math

import torch


def _tensors(value):
    """Every tensor inside nested dicts and lists (a state dict, an optimiser's state)."""
    if isinstance(value, torch.Tensor):
        yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from _tensors(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from _tensors(item)


# The parts of a learner's state an update changes: the networks, the temperature and their optimisers.
NETWORK_STATE = (
    'actor',
    'critic',
    'critic_target',
    'log_alpha',
    'actor_optimizer',
    'critic_optimizer',
    'alpha_optimizer',
)

# And, with a camera, its encoder and the encoder's optimiser.
CAMERA_STATE = ('encoder', 'encoder_optimizer')


def check_state(state) -> None:
    """Refuse a saved state whose structure or values no run of this learner can produce."""
    if not isinstance(state, dict):
        raise ValueError(f'a checkpoint is a dict, found {type(state).__name__}')
    for key in ('config', 'counters', 'gates', 'rng'):
        if not isinstance(state.get(key), dict):
            raise ValueError(f"'{key}' must be a dict, found {type(state.get(key)).__name__}")
    counters = state['counters']
    for key in ('episode', 'total_steps', 'updates'):
        value = counters.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f'counters.{key} must be an integer >= 0, found {value!r}')
    if counters['episode'] > counters['total_steps']:
        raise ValueError(
            f'counters.episode {counters["episode"]} exceeds counters.total_steps '
            f'{counters["total_steps"]} (an episode has at least one step)'
        )
    if not isinstance(counters.get('advice_total'), dict):
        raise ValueError('counters.advice_total must be a dict')
    for key in (*NETWORK_STATE, *CAMERA_STATE):
        if any(t.is_floating_point() and not torch.isfinite(t).all() for t in _tensors(state.get(key))):
            raise ValueError(f"'{key}' holds non-finite values (NaN or inf)")
    for key in ('actor_optimizer', 'critic_optimizer', 'alpha_optimizer', 'encoder_optimizer'):
        _check_steps(key, state.get(key))
    for key in ('d_queue', 'e_queue'):
        values = state['gates'].get(key)
        if not isinstance(values, list) or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f'gates.{key} must be a list of finite numbers')
    threshold = state['gates'].get('joint_threshold', 1.0)
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not 0.0 <= threshold <= 1.0:
        raise ValueError(f'gates.joint_threshold must be a number in [0, 1], found {threshold!r}')
    _check_shifted(state['gates'].get('shifted', [-1, -1, []]))


def _check_steps(key: str, optimizer) -> None:
    """An optimiser's step counts: one per weight, all equal and >= 0, since an update steps a
    network's weights together (the compiled Adam step reads one count per network, update.adam_)."""
    if not isinstance(optimizer, dict):
        return  # absent (no camera), or refused by the loader's own structure check
    per_weight = optimizer.get('state', {})
    counts = [
        weight['step']
        for weight in (per_weight.values() if isinstance(per_weight, dict) else [])
        if isinstance(weight, dict) and isinstance(weight.get('step'), (torch.Tensor, int, float))
    ]
    if any(isinstance(count, torch.Tensor) and count.numel() != 1 for count in counts):
        raise ValueError(f"'{key}' holds a step count that is not one number")
    steps = {float(count) for count in counts}
    if len(steps) > 1 or any(step < 0 for step in steps):
        raise ValueError(f"'{key}' holds step counts {sorted(steps)}: one count >= 0, the same for every weight")


def _check_shifted(shifted) -> None:
    """gates.shifted (random_ask_steps): [episode, last step seen, steps to ask at], integers."""
    ok = isinstance(shifted, (list, tuple)) and len(shifted) == 3 and isinstance(shifted[2], (list, tuple))
    numbers = [*shifted[:2], *shifted[2]] if ok else []
    if not ok or not all(isinstance(v, int) and not isinstance(v, bool) and v >= -1 for v in numbers):
        raise ValueError(f'gates.shifted must be [episode, step, [steps]] of integers >= -1, found {shifted!r}')


def check_camera(state: dict, camera) -> None:
    """Refuse a saved state for another camera than ``camera`` (a CameraSpec, or None: none)."""
    import dataclasses

    saved, own = state.get('camera'), None if camera is None else dataclasses.asdict(camera)
    if saved != own:
        raise ValueError(f'checkpoint is for camera {saved}, this learner reads {own}')


def resumed_settings(saved_config: dict) -> list:
    """The run-time (dynamic) LearnerConfig fields a checkpoint's config holds."""
    from .config import CONFIG_FIELDS

    return [name for name, f in CONFIG_FIELDS.items() if f.metadata['dynamic'] and name in saved_config]


# Settings that change how fast a run goes, not what it learns: a resume may change them unsaid.
SPEED_SETTINGS = ('device', 'compile_update')


def resumed_changes(saved_config: dict, config) -> list:
    """The settings a resume changes from those its checkpoint was saved with, each as 'name now
    (was saved)': a resumed run learns on with them, which a person should hear (a mode or a
    learning rate changed by a params file edited since). The run-time settings come back as
    saved (resumed_settings), hidden layers must match, and SPEED_SETTINGS are left out."""
    from .config import CONFIG_FIELDS, ros_name

    now = config.to_dict()
    return [
        f'{ros_name(f)} {now[name]!r} (was {saved_config[name]!r})'
        for name, f in CONFIG_FIELDS.items()
        if name in saved_config
        and not f.metadata['dynamic']
        and name not in SPEED_SETTINGS
        and saved_config[name] != now[name]
    ]
