"""The EQ-HRL learning core. Imports no ROS module: nodes, scripts and tests all drive it.

- config.py      every hyperparameter once (default, range, description); the modes
- equations.py   every equation of the paper (Eqs. 4-10), named as the paper names it
- networks.py    the squashed-Gaussian actor and the twin critics
- update.py      Algorithm 1's update, once: algorithm1_update (eager, compiled and seeds together)
- replay.py      replay memories D and D_advising
- advising.py    FIFO queues, dynamic/fixed thresholds and the early-advising budget
- learner.py     EQSACLearner: SAC, QASAC and EQSAC (Algorithm 1)
- compiled_update.py algorithm1_update compiled as one program (compile_update)
- experts.py     the expert interface and built-in controllers
- imperfect_experts.py delayed and weak experts (studies)
- simulated_human.py a simulated person (reaction times, noise, skips)
- teleop.py      a person's commands and answer window
- expert_factory.py the expert a backend name stands for (above the experts it builds)
- checkpoint.py  safe checkpoints and exported policies
- signing.py     a deployment's shared key: signed weights, batches and commands (HMAC)
- env_spec.py    EnvSpec: an env's spaces, pace and success rule, whoever announces it; ActionScaler
- envs.py        gymnasium envs: construction, their EnvSpec, action labels
- evaluation.py  the advice-free evaluation of a policy
- errors.py      the errors the core raises
- training.py    the in-process training loop (one seed, or seeds together)
- seed_batch.py  SeedBatch: many seeds' updates as one (one batched product per layer)
- trainer.py     Trainer: learning fed by actor nodes (acting and learning apart)
- transitions.py batches of transitions on their way to the trainer; the actor's outbox
- weights.py     the networks an actor needs, as safetensors bytes
- summary.py     one episode's statistics (the record's fields)
- records.py     a run's folder: episodes.csv and where saves go
- resume_point.py a lone in-process run saved between episodes and resumed exactly
"""

import importlib

# Names and the module that holds each. Loaded on first use (PEP 562), so that a light
# reader of core.summary or core.records does not pay for torch.
_HOME = {
    'AdvisingGates': 'advising',
    'FifoQueue': 'advising',
    'GateDecision': 'advising',
    'CheckpointError': 'checkpoint',
    'PolicyExpert': 'checkpoint',
    'export_policy': 'checkpoint',
    'load_checkpoint': 'checkpoint',
    'save_checkpoint': 'checkpoint',
    'ActionScaler': 'env_spec',
    'make_env': 'envs',
    'success_criterion': 'envs',
    'EnvSpec': 'env_spec',
    'gym_spec': 'envs',
    'Advice': 'experts',
    'AdviceRequest': 'experts',
    'heuristic_expert': 'experts',
    'make_expert': 'expert_factory',
    'EQSACLearner': 'learner',
    'LearnerConfig': 'learner',
    'Proposal': 'learner',
    'EpisodeSummary': 'summary',
    'run_episode': 'training',
    'train': 'training',
}
__all__ = sorted(_HOME)


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(importlib.import_module(f'.{_HOME[name]}', __name__), name)
