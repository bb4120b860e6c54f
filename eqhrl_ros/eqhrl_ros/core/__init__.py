"""The EQ-HRL learning core. Imports no ROS module: nodes, scripts and tests all drive it.

Five wings, each importing only the wings above it in this list (tests/core/test_import_graph.py):

data/       what is stored and what travels
  errors.py       the errors the core raises
  advice.py       AdviceRequest, Advice and the expert interface; the kinds of failed advice
  replay.py       replay memories D and D_advising
  camera_frames.py   a camera frame's fields to pixels, compressed frames decoded safely
  frame_replay.py camera frames held once, stacks gathered by index (D and D_advising with a camera)
  summary.py      one episode's statistics (the record's fields)
  batch_frames.py a camera's frames in a batch of transitions: each once, stacks by index
  transitions.py  batches of transitions on their way to the trainer; the actor's outbox
  weights.py      the networks an actor needs, as safetensors bytes; which trainer it follows
  signing.py      a deployment's shared key: signed weights, batches and commands (HMAC)
  torch_files.py  torch's zip files written atomically and read safely
envs/       an env as the learner sees it
  spec.py         EnvSpec: an env's spaces, pace and success rule, whoever announces it; ActionScaler; CameraSpec
  gymnasium_envs.py gymnasium envs: construction, their EnvSpec, action labels
  camera_envs.py  a gymnasium env seen through a camera: its rendering, resized and stacked
algorithm/  EQ-HRL itself
  config.py       every hyperparameter once (default, range, description); the modes
  equations.py    every equation of the paper (Eqs. 4-10), named as the paper names it
  networks.py     the squashed-Gaussian actor and the twin critics
  image_encoder.py   a conv encoder of frame stacks (DrQ-v2), random-shift augmentation
  streams.py      the learner's random streams, one per purpose
  observations.py what the networks read, checked: a vector, or a state vector and a camera's frame stack
  policy.py       Policy: pi(.|s), the actor that acts, and E(s)
  critics.py      Critics: the twin critics, their targets, and D(s)
  memories.py     ReplayMemories: D and D_advising, and an update's batches from both
  update.py       Algorithm 1's update, once: algorithm1_update (eager, compiled and stacked seeds)
  compiled_update.py algorithm1_update compiled as one program (compile_update), acting ahead after it
  acting_ahead.py what the compiled update computed for the next observation, taken where it still holds
  updater.py      Updater: the temperature, the optimisers, the update's inputs, the compile, the losses
  stacked_seeds.py   StackedSeeds: many seeds' updates as one (one batched product per layer)
  advice_window.py   whether advice is open now: the budgets in episodes (Eq. 7) and in seconds
  advising.py     the gates: FIFO queues, dynamic/fixed thresholds (Eq. 10)
  state_scores.py    a state's novelty and the advice's gain near it (two gates beyond the paper)
  advice_counts.py   what advice cost and brought, per episode and over the run
  advice_outcomes.py what came of each request and each step the person drove, counted
  learner_state.py   a saved learner state, checked
  cpu_threads.py  torch's CPU threads fitted to the machine: all while the cores are free, one while crowded
  learner.py      EQSACLearner: SAC, QASAC and EQSAC (Algorithm 1), wired from the parts above
experts/    whoever answers a request
  controllers.py  the built-in controllers of the shipped envs
  policy.py       an exported policy and the expert that serves it
  simulated_human.py a simulated person (reaction times, noise, skips)
  imperfect.py    delayed and weak experts (studies)
  teleop.py       a person's commands and answer window
  takeover.py     the person's takeover rule: when their command replaces the learner's action
  wheel.py        asking for the wheel: a real-time request the person takes and hands back
  factory.py      the expert a backend name stands for (above the experts it builds)
runs/       a run from start to end
  in_process.py     the in-process training loop (one seed, or seeds together)
  trainer.py      Trainer: learning fed by actor nodes (acting and learning apart)
  checkpoint.py   checkpoints with their replay memories
  resume_point.py a lone in-process run saved between episodes and resumed exactly
  provenance.py   what made a run: its commit, version and tree state (provenance.yaml)
  records.py      a run's folder: episodes.csv and where saves go
  evaluation.py   the advice-free evaluation of a policy
"""

import importlib

# Names and the module that holds each. Loaded on first use (PEP 562), so that a light
# reader of core.data.summary or core.runs.records does not pay for torch.
_HOME = {
    'AdvisingGates': 'algorithm.advising',
    'FifoQueue': 'algorithm.advising',
    'GateDecision': 'algorithm.advising',
    'CheckpointError': 'data.errors',
    'PolicyExpert': 'experts.policy',
    'export_policy': 'experts.policy',
    'load_checkpoint': 'runs.checkpoint',
    'save_checkpoint': 'runs.checkpoint',
    'ActionScaler': 'envs.spec',
    'make_env': 'envs.gymnasium_envs',
    'success_criterion': 'envs.gymnasium_envs',
    'EnvSpec': 'envs.spec',
    'gym_spec': 'envs.gymnasium_envs',
    'Advice': 'data.advice',
    'AdviceRequest': 'data.advice',
    'heuristic_expert': 'experts.controllers',
    'make_expert': 'experts.factory',
    'EQSACLearner': 'algorithm.learner',
    'LearnerConfig': 'algorithm.config',
    'Proposal': 'algorithm.learner',
    'EpisodeSummary': 'data.summary',
    'run_episode': 'runs.in_process',
    'train': 'runs.in_process',
}
__all__ = sorted(_HOME)


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(importlib.import_module(f'.{_HOME[name]}', __name__), name)
