"""The in-process training loop: Algorithm 1 with a gymnasium env and an expert callable."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence

import gymnasium as gym

from .evaluation import evaluate
from ..data.advice import Expert
from ..algorithm.config import advice_protocol, asks_for_advice
from ..experts.wheel import AskedWheel, WheelRules
from ..algorithm.learner import EpisodeSummary, EQSACLearner, Resolution
from ..data.advice import AdviceRequest


def ask_expert(learner: EQSACLearner, proposal, expert: Optional[Expert]) -> Resolution:
    """Call the expert for a fired gate; any exception counts as a failed request, never a crash."""
    if expert is None:
        return learner.resolve_advice(proposal, failure='unavailable')
    try:
        advice = expert(proposal.request)
    except Exception:  # an expert's bug must not end training; it is counted instead
        return learner.resolve_advice(proposal, failure='error')
    return learner.resolve_advice(proposal, advice)


class _Acting:
    """One run's half of Algorithm 1's step that acts: observe, propose, ask, step the env."""

    def __init__(self, env: gym.Env, learner: EQSACLearner, expert: Optional[Expert], on_proposal=None):
        self.env, self.learner, self.expert, self.on_proposal = env, learner, expert, on_proposal
        self.observe = getattr(expert, 'observe', None)
        # An expert that takes over unasked (simulated_human.SimulatedHuman with a TakeoverRule).
        self.intervene: Optional[Callable] = getattr(expert, 'intervene', None) if getattr(expert, 'takeover', None) else None
        self.obs: Any = None  # the env's observation, after the first reset
        self.new_episode = True
        # The wheel protocol in simulated time (a lock-step env is 'answer' unless told otherwise):
        # the person is asked to take over and drives until they hand back (core/experts/wheel.py).
        self.wheel_protocol = advice_protocol(learner.config.advice_protocol, realtime=False) == 'wheel'
        if self.wheel_protocol and not hasattr(expert, 'wheel_command'):
            raise ValueError(
                'advice_protocol wheel in-process needs an expert that can take the wheel '
                '(simulated_human.SimulatedHuman), not a controller answering one state'
            )
        self.person: Any = expert  # for the wheel: a SimulatedHuman (alerted, wheel_command)
        self.step_s = float(getattr(expert, 'step_s', 0.05))  # simulated seconds per env step
        self.steps = 0
        self.open: Optional[AskedWheel] = None

    def reset(self, seed: Optional[int] = None) -> None:
        self.obs, _ = self.env.reset(seed=seed)
        self.new_episode = True

    def act(self) -> tuple:
        """(obs, action, reward, next_obs, terminated, truncated, advised) of one env step."""
        learner, obs, new_episode = self.learner, self.obs, self.new_episode
        self.new_episode = False
        if self.observe is not None:
            self.observe(obs, new_episode)
        proposal = learner.propose(obs)
        if self.on_proposal is not None:
            self.on_proposal(learner, proposal)
        taken = self._taken_over(proposal, new_episode) if self.intervene is not None else None
        if self.open is not None:  # a request for the wheel is open: the person drives, or will
            action, advised = self._wheel_turn(proposal)
        elif taken is not None:  # the person steers this step: no request, their action goes
            action, advised = learner.take_over(proposal, *taken).action_and_advised()
        elif proposal.decision.fire and self.wheel_protocol:
            config = learner.config
            take_s = min(config.wheel_take_s, learner.person_budget_left_s)
            rules = WheelRules(max(take_s, 1e-3), config.wheel_max_s, config.wheel_agree, config.wheel_agree_steps)
            self.open = AskedWheel(self.now, rules, learner.scaler, stale_s=self.step_s * 1.5)
            self.person.alerted(self.now)
            action, advised = proposal.action, False  # the learner drives until the person takes the wheel
        elif proposal.decision.fire:
            action, advised = ask_expert(learner, proposal, self.expert).action_and_advised()
        else:
            action, advised = proposal.action, False
        next_obs, reward, terminated, truncated, _ = self.env.step(action)
        self.obs = next_obs
        self.steps += 1
        if (terminated or truncated) and self.open is not None:
            turn = self.open.end_episode(self.now)
            learner.count_person_seconds(turn.seconds, asked=True)
            learner.end_wheel_request(turn.ended, turn.taken)
            self.open = None
        return obs, action, reward, next_obs, terminated, truncated, advised

    @property
    def now(self) -> float:
        """Simulated seconds since the run began."""
        return self.steps * self.step_s

    def _wheel_turn(self, proposal) -> tuple:
        learner, low, high = self.learner, self.learner.scaler.low, self.learner.scaler.high
        request = AdviceRequest(
            self.obs, proposal.action, low, high, float('nan'), float('nan'), learner.episode, learner.episode_step
        )
        person = self.person.wheel_command(request, self.now)
        assert self.open is not None  # called only with a request open
        turn = self.open.step(person, proposal.action, self.now, learner.person_budget_left_s)
        learner.count_person_seconds(turn.seconds, asked=True)
        if turn.ended:
            learner.end_wheel_request(turn.ended, turn.taken)
            self.open = None
        if turn.action is None:
            return proposal.action, False
        return learner.drive_asked(proposal, turn.action).action_and_advised()

    def _taken_over(self, proposal, new_episode: bool):
        """The simulated person's takeover of this step, inside the advising budget (the episodes and
        the person's seconds) of a mode that keeps advice, or None."""
        learner = self.learner
        if self.intervene is None or not learner.advice_window().open:
            return None
        low, high = learner.scaler.low, learner.scaler.high
        request = AdviceRequest(
            self.obs, proposal.action, low, high, float('nan'), float('nan'), learner.episode, learner.episode_step
        )
        return self.intervene(request, new_episode)


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
    acting = _Acting(env, learner, expert, on_proposal)
    acting.reset(seed)
    while True:
        obs, action, reward, next_obs, terminated, truncated, advised = acting.act()
        summary = learner.step(obs, action, reward, next_obs, terminated, truncated, advised)
        if summary is not None:
            return summary


def train(
    env: gym.Env,
    learner: EQSACLearner,
    episodes: int,
    expert: Optional[Expert] = None,
    seed: Optional[int] = None,
    on_episode: Callable[[EpisodeSummary], None] | None = None,
    evaluation: Optional['Evaluation'] = None,
    on_proposal: Callable | None = None,
    between_episodes: Callable[[], None] | None = None,
) -> list[EpisodeSummary]:
    """Run episodes until the learner's episode index reaches ``episodes`` (resumes count).
    ``seed``: the first reset's seed (None: the env's stream goes on, as after a resume);
    ``evaluation``: the advice-free evaluation every ``evaluation.every`` episodes;
    ``on_proposal``: see run_episode; ``between_episodes``: called after each episode is
    recorded and evaluated, where the run can be saved (resume_point.py)."""
    summaries = []
    first = True
    while learner.episode < episodes:
        summary = run_episode(env, learner, expert, seed=seed if first else None, on_proposal=on_proposal)
        first = False
        summaries.append(summary)
        if on_episode is not None:
            on_episode(summary)
        _evaluate_if_due(evaluation, learner, episodes)
        if between_episodes is not None:
            between_episodes()
    return summaries


def _evaluate_if_due(evaluation: Optional['Evaluation'], learner: EQSACLearner, episodes: int) -> None:
    if evaluation is not None and (learner.episode % evaluation.every == 0 or learner.episode == episodes):
        evaluation.on_result(evaluate(evaluation.env, learner, evaluation.starts))


@dataclass(eq=False)
class SeedRun:
    """One seed's part in train_stacked(): what train() takes for a lone run."""

    env: gym.Env
    learner: EQSACLearner
    expert: Optional[Expert] = None
    seed: Optional[int] = None  # the first reset's seed
    on_episode: Callable[[EpisodeSummary], None] | None = None
    evaluation: Optional['Evaluation'] = None
    on_proposal: Callable | None = None
    on_finished: Callable[[], None] | None = None  # called once its learner reaches ``episodes``


def train_stacked(runs: Sequence[SeedRun], episodes: int) -> None:
    """train() for runs that differ only in their seed, with their updates as one (stacked_seeds.py).

    Each run acts exactly as it would alone; after every env step of all of them, the
    learners (which would each update alone at that point) update in one StackedSeeds.update().
    A run leaves when its learner reaches ``episodes`` (its on_finished is then called); the
    others go on. The learners must be at the same step (fresh ones are).
    """
    stacked = StackedSeedRuns(runs, episodes)
    try:
        while not stacked.done:
            stacked.step()
    finally:
        stacked.close()


class StackedSeedRuns:
    """train_stacked(), one env step at a time (benchmarks drive it too)."""

    def __init__(self, runs: Sequence[SeedRun], episodes: int):
        if len({run.learner.total_steps for run in runs}) > 1:
            raise ValueError('runs learn together only from the same step; these learners are at different steps')
        self.episodes = episodes
        self.active = []
        for run in runs:
            if run.learner.episode < episodes:
                acting = _Acting(run.env, run.learner, run.expert, run.on_proposal)
                acting.reset(run.seed)
                self.active.append((run, acting))
        self.stacked = self._stack()

    def _stack(self):
        from ..algorithm.stacked_seeds import StackedSeeds

        return StackedSeeds([run.learner for run, _ in self.active]) if self.active else None

    @property
    def done(self) -> bool:
        return not self.active

    def step(self) -> None:
        """One env step of every active run, then their update, then the episodes that ended."""
        ended = []
        for run, acting in self.active:
            obs, action, reward, next_obs, terminated, truncated, advised = acting.act()
            run.learner.count_step(obs, action, reward, next_obs, terminated, advised)
            ended.append(terminated or truncated)
        self.stacked.updates_after_a_step()  # where each lone learner's step() updates
        finished = []
        for (run, acting), done in zip(self.active, ended):
            if not done:
                continue
            summary = run.learner.end_episode()
            if run.on_episode is not None:
                run.on_episode(summary)
            _evaluate_if_due(run.evaluation, run.learner, self.episodes)
            if run.learner.episode >= self.episodes:
                finished.append(run)
            else:
                acting.reset()
        if finished:
            # The stack is remade of the runs that go on; the finished ones keep their weights.
            self.stacked.release()
            self.active = [(run, acting) for run, acting in self.active if run not in finished]
            self.stacked = self._stack()
            for run in finished:
                if run.on_finished is not None:
                    run.on_finished()

    def close(self) -> None:
        """Give every learner its weights back (the stacked tensors are dropped)."""
        if self.stacked is not None:
            self.stacked.release()
            self.stacked = None


@dataclass
class Evaluation:
    """What train() needs for the advice-free evaluation (core/runs/evaluation.py)."""

    env: gym.Env  # an env of its own: the training env's state and random stream stay untouched
    every: int  # episodes between evaluations (and one after the last episode)
    starts: Sequence[int]  # reset seeds of the fixed start states (evaluation.eval_seeds)
    on_result: Callable[[list], None]  # gets the EvalEpisode of each start
