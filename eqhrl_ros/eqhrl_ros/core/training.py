"""The in-process training loop: Algorithm 1 with a gymnasium env and an expert callable."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import gymnasium as gym

from .evaluation import evaluate
from .experts import Expert
from .learner import EpisodeSummary, EQSACLearner, Resolution


def ask_expert(learner: EQSACLearner, proposal, expert: Optional[Expert]) -> Resolution:
    """Call the expert for a fired gate; any exception counts as a failed request, never a crash."""
    if expert is None:
        return learner.resolve_advice(proposal, failure='unavailable')
    try:
        advice = expert(proposal.request)
    except Exception:  # an expert's bug must not end training; it is counted instead
        return learner.resolve_advice(proposal, failure='error')
    return learner.resolve_advice(proposal, advice)


def run_episode(
    env: gym.Env,
    learner: EQSACLearner,
    expert: Optional[Expert] = None,
    seed: Optional[int] = None,
    on_proposal: Callable | None = None,
) -> EpisodeSummary:
    """One episode of Algorithm 1's outer loop. The env must end episodes (a TimeLimit).
    An expert with an ``observe(obs, new_episode)`` method is shown every observation
    (imperfect_experts.DelayedExpert); ``on_proposal(learner, proposal)`` sees every gate decision."""
    obs, _ = env.reset(seed=seed)
    observe = getattr(expert, 'observe', None)
    new_episode = True
    while True:
        if observe is not None:
            observe(obs, new_episode)
            new_episode = False
        proposal = learner.propose(obs)
        if on_proposal is not None:
            on_proposal(learner, proposal)
        if proposal.decision.fire:
            action, advised = ask_expert(learner, proposal, expert).take()
        else:
            action, advised = proposal.action, False
        next_obs, reward, terminated, truncated, _ = env.step(action)
        summary = learner.step(obs, action, reward, next_obs, terminated, truncated, advised)
        if summary is not None:
            return summary
        obs = next_obs


def train(
    env: gym.Env,
    learner: EQSACLearner,
    episodes: int,
    expert: Optional[Expert] = None,
    seed: Optional[int] = None,
    on_episode: Callable[[EpisodeSummary], None] | None = None,
    evaluation: Optional['Evaluation'] = None,
    on_proposal: Callable | None = None,
) -> list[EpisodeSummary]:
    """Run episodes until the learner's episode index reaches ``episodes`` (resumes count).
    ``evaluation``: the advice-free evaluation every ``evaluation.every`` episodes;
    ``on_proposal``: see run_episode."""
    summaries = []
    first = True
    while learner.episode < episodes:
        summary = run_episode(env, learner, expert, seed=seed if first else None, on_proposal=on_proposal)
        first = False
        summaries.append(summary)
        if on_episode is not None:
            on_episode(summary)
        if evaluation is not None and (learner.episode % evaluation.every == 0 or learner.episode == episodes):
            evaluation.on_result(evaluate(evaluation.env, learner, evaluation.starts))
    return summaries


@dataclass
class Evaluation:
    """What train() needs for the advice-free evaluation (core/evaluation.py)."""

    env: gym.Env  # an env of its own: the training env's state and random stream stay untouched
    every: int  # episodes between evaluations (and one after the last episode)
    starts: Sequence[int]  # reset seeds of the fixed start states (evaluation.eval_seeds)
    on_result: Callable[[list], None]  # gets the EvalEpisode of each start
