"""An experiment's settings: a params file's sections checked as the nodes would check them, with the
command line's overrides; the learner configuration and the expert of one run. No ROS here."""

from __future__ import annotations

import math
import shlex
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

from ..files.paths import params_file
from ..files.yaml_files import load_mapping

DEFAULT_EPISODES = 200  # --episodes where neither it nor the params file's max_episodes is set


@dataclass
class Settings:
    env_id: str
    learner: dict  # learner node parameters from the params file
    max_episode_steps: int
    episodes: int
    expert_backend: str = 'heuristic'
    policy_path: str = ''
    params_path: str = ''
    env_node: str = ''  # a command that starts the user's env node (--env-node), or ''
    file_env_node: str = 'gym_env'  # the shipped env node the params file is for (launching.env_node_for)
    eval_every: int = 0  # advice-free evaluation every N episodes (in-process runs; 0: none)
    eval_starts: int = 10  # fixed start states of each evaluation
    # An imperfect expert (in-process runs; eqhrl-study): 'human' (simulated_human.HumanLimits
    # fields, the expert backend then simulated_human), 'delay_steps', 'gain' (imperfect_experts).
    expert_options: dict = field(default_factory=dict)
    gate_trace: bool = False  # write <run>/gates.csv: D(s), E(s) and thresholds inside the budget
    # A lone in-process run saves its state between episodes this often (seconds; 0: never),
    # and an interrupted one continues from there (core/runs/resume_point.py). --save-every.
    save_every_s: float = 300.0


def load_settings(args) -> Settings:
    """The params file's sections, refused as the nodes would refuse them (a typo included)."""
    from ..nodes.launching import env_node_for  # no ROS in it: the rule eqhrl-train and the launch files use
    from ..parameters import (
        EXPERT_PARAMS,
        GYM_ENV_PARAMS,
        LEARNER_CONFIG_PARAMS,
        LEARNER_NODE_PARAMS,
        check_section,
        default_of,
        file_section,
    )

    path = params_file(args.params)
    data = load_mapping(path, 'params file')
    learner = file_section(data, 'learner')
    expert = file_section(data, 'expert')
    check_section('learner', learner, LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS)
    # The env node the file is for. Before, a file for the example env (params/double_integrator.yaml:
    # no env_id) ran Pendulum-v1 in-process, silently, in eqhrl-experiment and eqhrl-study alike.
    file_env_node = 'gym_env' if args.env_node else env_node_for(data)
    env = file_section(data, file_env_node)
    if file_env_node == 'gym_env':
        check_section('gym_env', env, GYM_ENV_PARAMS)
    elif not (args.env or learner.get('env_id')):
        if not args.through_ros:
            raise ValueError(
                f'{path.name} is for the env node {file_env_node}, which is no gymnasium env, and an in-process '
                'run needs one: run the file through ROS (eqhrl-experiment --through-ros), or name a gymnasium '
                "env (--env, or env_id in a study plan's learner settings)"
            )
    check_section('expert', expert, EXPERT_PARAMS)
    if args.budget is not None:
        learner['advising_budget'] = args.budget
    if getattr(args, 'record', False):
        learner['record'] = True
    if getattr(args, 'prior', None):
        learner['prior'] = [str(Path(p).resolve()) for p in args.prior]
    save_every = getattr(args, 'save_every', None)
    if save_every is not None and not (save_every >= 0 and math.isfinite(save_every)):
        raise ValueError(f'--save-every must be >= 0 minutes (0: never), got {save_every}')
    if args.eval_every < 0 or args.eval_starts < 1:
        raise ValueError(
            f'--eval-every must be >= 0 and --eval-starts >= 1 (got {args.eval_every}, {args.eval_starts})'
        )
    if args.env_node:
        if not args.through_ros:
            raise ValueError('--env-node runs an env node, so it needs --through-ros')
        env_node_command(args.env_node, 0, 1)  # refuses an empty command or a program not found
    env_id = args.env or learner.get('env_id') or env.get('env_id')
    if not env_id and file_env_node == 'gym_env' and not args.env_node:
        env_id = default_of(GYM_ENV_PARAMS, 'env_id')
    settings = Settings(
        env_id=env_id or '',
        learner=learner,
        max_episode_steps=args.max_steps
        or int(env.get('max_episode_steps', default_of(GYM_ENV_PARAMS, 'max_episode_steps'))),
        # A learner node's max_episodes of 0 means "never stop"; a run of experiments needs an end.
        episodes=args.episodes or int(learner.get('max_episodes', 0)) or DEFAULT_EPISODES,
        expert_backend=args.expert or expert.get('backend', default_of(EXPERT_PARAMS, 'backend')),
        policy_path=args.policy_path or expert.get('policy_path', default_of(EXPERT_PARAMS, 'policy_path')),
        params_path=str(path),
        env_node=args.env_node or '',
        file_env_node=file_env_node,
        eval_every=0 if args.through_ros else args.eval_every,
        eval_starts=args.eval_starts,
    )
    if save_every is not None:
        settings.save_every_s = 60.0 * save_every
    if learner.get('prior') and settings.env_id:
        check_prior(learner['prior'], settings)
    return settings


def check_prior(sources, settings: Settings) -> None:
    """Refuse, before anything runs, a prior that is missing or was made on other spaces."""
    from ..core import make_env
    from ..files.mcap_record import RecordError, load_prior

    env = make_env(settings.env_id, settings.max_episode_steps)
    try:
        load_prior(sources, int(env.observation_space.shape[0]), env.action_space.low, env.action_space.high)
    except RecordError as error:
        raise ValueError(f'prior: {error}') from error
    finally:
        env.close()


def learner_config(settings: Settings, algorithm: str, seed: int):
    from ..core import LearnerConfig
    from ..parameters import LEARNER_NODE_PARAMS

    return LearnerConfig.from_params(
        settings.learner, node_keys=[p.name for p in LEARNER_NODE_PARAMS], mode=algorithm, seed=seed
    )


def make_expert(settings: Settings, seed: int = 0):
    """The run's expert: the backend of the settings, made imperfect by expert_options: 'human'
    (HumanLimits fields: a simulated person), 'takeover' (TakeoverRule fields: that person also
    takes over unasked), 'gain', 'delay_steps'."""
    from ..core.experts.factory import make_expert as expert_for
    from ..core.experts.imperfect import DelayedExpert, WeakExpert
    from ..core.experts.simulated_human import HumanLimits, TakeoverRule

    if settings.expert_backend == 'none':
        return None
    options = dict(settings.expert_options)
    unknown = sorted(set(options) - {'human', 'takeover', 'delay_steps', 'gain'})
    if unknown:
        raise ValueError(f'unknown expert option(s) {unknown}; known: human, takeover, delay_steps, gain')
    person = 'human' in options or 'takeover' in options
    backend = 'simulated_human' if person else settings.expert_backend
    limits = _built(HumanLimits, 'human', options.get('human', {})) if person else None
    takeover = _built(TakeoverRule, 'takeover', options['takeover']) if 'takeover' in options else None
    if takeover is not None and (options.get('gain', 1.0) != 1.0 or options.get('delay_steps', 0)):
        raise ValueError("expert option 'takeover' goes with a simulated person alone (no gain or delay_steps)")
    # The person's own random stream: one per seed, apart from the learner's.
    expert = expert_for(backend, settings.env_id, settings.policy_path, limits, seed=10_000 + seed, takeover=takeover)
    if options.get('gain', 1.0) != 1.0:
        expert = WeakExpert(expert, options['gain'])
    if options.get('delay_steps', 0):
        expert = DelayedExpert(expert, options['delay_steps'])
    return expert


def env_node_command(template: str, seed: int, max_steps: int) -> list:
    """The user's env node command with {seed} and {max_steps} filled in. A program that is not
    on PATH but in this environment's bin (the package's own nodes, in a venv) is found there."""
    words = shlex.split(template.format(seed=seed, max_steps=max_steps))
    if not words:
        raise ValueError('--env-node is empty')
    found = shutil.which(words[0]) or shutil.which(words[0], path=str(Path(sys.prefix) / 'bin'))
    if found is None:
        raise ValueError(f'--env-node: {words[0]!r} is neither on PATH nor in {Path(sys.prefix) / "bin"}')
    return [found, *words[1:]]


def _built(kind, option: str, values):
    """``kind(**values)`` for expert option ``option``, or a ValueError that names it."""
    if not isinstance(values, dict):
        raise ValueError(f"expert option '{option}' must be a mapping of {kind.__name__} fields, got {values!r}")
    try:
        return kind(**values)
    except TypeError as error:
        raise ValueError(f"expert option '{option}': {error}") from error
