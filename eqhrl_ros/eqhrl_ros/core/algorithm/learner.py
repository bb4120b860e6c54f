"""EQSACLearner: SAC, QASAC and EQSAC (Algorithm 1 of the paper), made of parts.

One step of Algorithm 1, as the caller drives it:

    proposal = learner.propose(obs)                  # a_t ~ pi(.|s_t); D(s), E(s); the gates
    if proposal.decision.fire:                       # Eq. 7 and Eq. 10
        action, advised = learner.resolve_advice(proposal, expert(proposal.request)).action_and_advised()
    else:
        action, advised = proposal.action, False
    next_obs, reward, terminated, truncated, _ = env.step(action)
    summary = learner.step(obs, action, reward, next_obs, terminated, truncated, advised)
                                                     # store in D (and D_advising); update()

The parts, each with one job (this class only wires them and counts the episode):
- ``observation`` (observations.py): what the networks read, checked;
- ``policy`` (policy.py): pi(.|s), the actor that acts, and E(s) of it;
- ``critics`` (critics.py): Q_theta1, Q_theta2, their targets, and D(s);
- ``gates`` (advising.py) and ``budget`` (advice_window.py): whether to ask, and whether advice is open;
- ``memories`` (memories.py): D and D_advising;
- ``updater`` (updater.py): the temperature, the optimisers, the update (eager or compiled), its losses,
  and what the compiled update computed ahead for the next observation (acting_ahead.py);
- ``streams`` (streams.py): one random stream per purpose;
- ``tally`` (advice_counts.py): the run's episodes, steps and advice counts.

The caller may be a plain loop (core/runs/in_process.py) or a ROS node; the learner never
knows who answers advice. Every equation it uses lives in core/algorithm/equations.py.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Optional

import numpy as np
import torch

from ..data.advice import Advice, AdviceRequest
from ..data.summary import EpisodeSummary
from ..envs.spec import ActionScaler, CameraSpec, SuccessCriterion
from . import advice_outcomes as outcomes
from .advice_counts import AdviceCounts, RunTally
from .advice_outcomes import Proposal, Resolution
from .advice_window import AdviceBudget, AdviceWindow
from .advising import GateDecision, gates_for
from .config import SCORE_MODES, LearnerConfig, check_value
from .critics import Critics
from .learner_state import check_camera, check_state, resumed_changes, resumed_settings
from .memories import ReplayMemories
from .networks import SquashedGaussianActor, TwinCritic, check_fits_in_memory
from .observations import CameraObservation, VectorObservation
from .policy import Policy
from .state_scores import StateScores
from .streams import RandomStreams, stream_seeds
from .updater import Updater, updates_after_a_step


def learning_device(name: str) -> torch.device:
    """The torch device for LearnerConfig.device, or a ValueError that says what is missing."""
    if name == 'cuda' and not torch.cuda.is_available():
        raise ValueError(
            "device 'cuda' was asked for, but torch sees no GPU (torch.cuda.is_available() is False; "
            f'this torch is {torch.__version__}, and the CPU build has no CUDA); use device cpu'
        )
    return torch.device(name)


def initial_networks(obs_dim: int, action_dim: int, config: LearnerConfig, device, observation=None) -> tuple:
    """(actor, twin critic) initialised from the seed without disturbing the caller's global RNG,
    on the CPU: the same initial weights on every device. ``observation``: a camera's part makes
    its encoder after them, from the same stream."""
    check_fits_in_memory(obs_dim, action_dim, config.hidden, torch.device(device))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(stream_seeds(config.seed)['networks'])
        actor = SquashedGaussianActor(obs_dim, action_dim, config.hidden).to(device)
        critic = TwinCritic(obs_dim, action_dim, config.hidden).to(device)
        if observation is not None:
            observation.make_encoder()
    return actor, critic


class EQSACLearner:
    """Soft Actor-Critic with EQ-HRL advising gates and dual replay (SAC / QASAC / EQSAC)."""

    def __init__(
        self,
        obs_dim: int,
        action_low,
        action_high,
        config: LearnerConfig | None = None,
        success: SuccessCriterion | None = None,
        camera: CameraSpec | None = None,
    ):
        """``obs_dim``: the observation's vector; with a ``camera``, the state vector beside it
        (0: pixels alone), and an observation is {'state': vector, 'pixels': uint8 [k, H, W, C]}."""
        self.config = cfg = config or LearnerConfig()
        self.resumed_changes: list = []  # settings a resume changed from its checkpoint's (learner_state.py)
        self.device = learning_device(cfg.device)
        self.observation: VectorObservation | CameraObservation
        if camera is None:
            self.observation = VectorObservation(obs_dim, self.device)
        else:
            if cfg.mode in SCORE_MODES:
                raise ValueError(f"mode '{cfg.mode}' scores the state vector: not with a camera (yet)")
            self.observation = CameraObservation(obs_dim, camera, self.device)
        scaler = ActionScaler(action_low, action_high)
        self.success = success or SuccessCriterion()
        self.streams = RandomStreams(cfg.seed, self.device)
        actor, critic = initial_networks(self.observation.features_dim, scaler.dim, cfg, self.device, self.observation)
        self.policy = Policy(actor, scaler, self.observation, self.streams, cfg)
        self.critics = Critics(critic)
        self.budget = AdviceBudget(cfg)
        self.gates = gates_for(cfg, self.budget)
        # The compiled update acts ahead (acting_ahead.py): D(s) and the exact E(s) where the gates read them.
        acts = (self.gates.uses_discrepancy, self.gates.uses_entropy and cfg.entropy_estimator == 'exact')
        self.updater = Updater(cfg, self.policy, self.critics, self.device, acts=acts)
        self.memories = ReplayMemories(cfg, self.observation, scaler.dim, self.streams, self.device)
        # Modes novelty and advice_gain (extensions) score the state itself (state_scores.py).
        self.scores = (
            StateScores(obs_dim, cfg.gate_neighbours, cfg.gate_memory, self.device) if self.gates.uses_score else None
        )
        self.tally = RunTally()
        self._reported_success: Optional[bool] = None  # the env's own verdict on the episode, if any
        self._reset_episode()

    # ------------------------------------------------------------------ the parts' members, by their usual names

    obs_dim = property(lambda self: self.observation.dim)
    action_dim = property(lambda self: self.policy.action_dim)
    scaler = property(lambda self: self.policy.scaler)
    actor = property(lambda self: self.policy.actor)
    critic = property(lambda self: self.critics.critic)
    critic_target = property(lambda self: self.critics.critic_target)
    log_alpha = property(lambda self: self.updater.log_alpha)
    target_entropy = property(lambda self: self.updater.target_entropy)
    replay = property(lambda self: self.memories.replay)  # D
    advice_replay = property(lambda self: self.memories.advice_replay)  # D_advising
    rng = property(lambda self: self.streams)
    updates = property(lambda self: self.updater.updates)
    compiled_update = property(lambda self: self.updater.compiled)
    episode = property(lambda self: self.tally.episode)  # Eq. 7's "Iteration": the current episode's index
    total_steps = property(lambda self: self.tally.total_steps)
    advice_total = property(lambda self: self.tally.advice_total)
    episode_advice = property(lambda self: self._episode_advice)

    @property
    def log(self):
        """The compiler's logger (info, warning); None: Python's; a node sets its own."""
        return self.updater.log

    @log.setter
    def log(self, value) -> None:
        self.updater.log = value

    @property
    def mode(self) -> str:
        return self.config.mode

    @property
    def alpha(self) -> float:
        return self.updater.alpha

    # ------------------------------------------------------------------ acting

    def act(self, obs, deterministic: bool = False) -> np.ndarray:
        """The policy's action in env units, without gates or counters (evaluation)."""
        return self.policy.act(obs, deterministic)

    @torch.inference_mode()
    def propose(self, obs) -> Proposal:
        """a_t ~ pi(.|s_t), then D(s) (Eq. 8), E(s) (Eq. 9) and the gates (Eq. 7, Eq. 10)."""
        obs_t = self.observation.tensor(obs)
        features = self.observation.features(obs_t)  # what the networks read (a camera's: encoded)
        warming_up = self.total_steps < self.config.random_warmup_steps
        # What the last compiled update computed for this very observation, where it could (acting_ahead.py).
        acted = {} if warming_up else (self.updater.acted_ahead(obs_t) or {})
        if acted:
            mean, log_std, action = acted['mean'], acted['log_std'], acted['action']
        else:
            mean, log_std, action = self.policy.sample(features, warming_up)

        if self.person_budget_left_s <= 0.0:  # the person's seconds are spent: as outside Eq. 7's budget
            decision = GateDecision(False, within_budget=False)
        elif self.gates.needs_evaluation(self.episode):
            gates = self.gates
            discrepancy = entropy = None
            if gates.uses_discrepancy:
                discrepancy = (
                    float(acted['discrepancy'])
                    if 'discrepancy' in acted
                    else self.critics.discrepancy(features, action)
                )
            if gates.uses_entropy:
                entropy = float(acted['entropy']) if 'entropy' in acted else self.policy.entropy(mean, log_std)
            draw = self.streams.uniform('request') if gates.uses_draw else None
            score = None
            if self.scores is not None:  # scored against the states before it, then remembered
                state = obs_t[0]
                score = self.scores.novelty(state) if self.mode == 'novelty' else self.scores.advice_gain(state)
                self.scores.observe(state)
            decision = gates.decide(self.episode, discrepancy, entropy, draw, self.episode_step, score)
        else:
            decision = self.gates.decide(self.episode)

        env_action = self.policy.to_env(action)
        request = None
        if decision.fire:
            request = AdviceRequest(
                observation=obs_t[0, : self.observation.state_dim].cpu().numpy().copy(),  # the vector part
                proposed_action=env_action,
                action_low=self.scaler.low,
                action_high=self.scaler.high,
                discrepancy=decision.discrepancy,
                entropy=decision.entropy,
                episode=self.episode,
                step=self.episode_step,
                pixels=self.observation.pixels(obs),  # a camera's stack, for the person asked
            )
        return Proposal(env_action, decision, request)

    def resolve_advice(self, proposal: Proposal, advice: Advice | None = None, failure: str = '') -> Resolution:
        """Count how a request for one answer ended (``failure``: why no answer came; else ``advice``)
        and return what to do (advice_outcomes.resolve)."""
        resolution = outcomes.resolve(
            self._episode_advice, proposal, advice, failure, self.scaler, self.person_budget_left_s
        )
        if proposal.request is not None and self.scores is not None:
            self._remember_gain(self.observation.tensor(proposal.request.observation)[0], proposal, resolution)
        return resolution

    def _remember_gain(self, state, proposal: Proposal, resolution: Resolution) -> None:
        """advice_gain: how far the advised action was from the learner's own at ``state``."""
        if self.scores is not None and resolution.advised and state is not None:
            gain = np.abs(self.normalize(resolution.action) - self.normalize(proposal.action)).max()
            self.scores.answered_with(state, float(gain))

    def take_over(self, proposal: Proposal, action, seconds: float, starts: bool) -> Resolution:
        """The person took this step over unasked (advice_outcomes.take_over)."""
        memory = self.config.takeover_to_advice_memory
        return outcomes.take_over(self._episode_advice, proposal, action, seconds, starts, self.scaler, memory)

    def drive_asked(self, proposal: Proposal, action) -> Resolution:
        """A step the person drives because they were asked to take the wheel (advice_outcomes.drive_asked)."""
        resolution = outcomes.drive_asked(self._episode_advice, proposal, action, self.scaler)
        if self.scores is not None:  # each step driven is an answer at its state (the last one proposed)
            self._remember_gain(self.scores.last_seen, proposal, resolution)
        return resolution

    def end_wheel_request(self, ended: str, taken: bool) -> None:
        """A request for the wheel ended, taken or not (advice_outcomes.end_wheel_request)."""
        outcomes.end_wheel_request(self._episode_advice, ended, taken)

    def count_person_seconds(self, seconds: float, asked: bool) -> None:
        """The person's seconds on this step, as they pass (advice_outcomes.count_person_seconds)."""
        outcomes.count_person_seconds(self._episode_advice, seconds, asked)

    # ------------------------------------------------------------------ the budgets

    def set_advising_budget(self, episodes: int) -> None:
        """Change the early-advising budget (Eq. 7) while learning, e.g. from a person's console."""
        self.budget.set_episodes(episodes)

    def set_advising_budget_s(self, seconds: float) -> None:
        """Change the budget in the person's seconds (0: none) while learning."""
        self.budget.set_seconds(seconds)

    @property
    def human_time_total_s(self) -> float:
        """The person's seconds over the run so far (requests and unasked takeovers), this
        episode's included: what advising_budget_s is spent against."""
        return self.tally.person_seconds(self._episode_advice)

    @property
    def person_budget_left_s(self) -> float:
        """Seconds of the person's budget left (inf when advising_budget_s is 0)."""
        return self.advice_window().seconds_left

    def advice_window(self) -> AdviceWindow:
        """Whether advice is open now, and what is left of the budgets (advice_window.py)."""
        return self.budget.window(self.episode, self.human_time_total_s)

    # ------------------------------------------------------------------ storing and learning

    def normalize(self, action) -> np.ndarray:
        """An action in env units as stored in D: mapped to [-1, 1] and clipped there."""
        return self.policy.normalize(action)

    def store(self, obs, normalized_action, reward: float, next_obs, terminated: bool, advised: bool) -> None:
        """(s_t, a_t, r_t, s_{t+1}) into D, and into D_advising when advised (memories.py)."""
        self.memories.store(obs, normalized_action, reward, next_obs, terminated, advised)

    def add_prior(
        self, observations, normalized_actions, rewards, next_observations, terminated, pixels=None, next_pixels=None
    ) -> int:
        """Earlier runs' advised transitions as prior data, before the first step (memories.py);
        with a camera, ``pixels`` and ``next_pixels`` their stacks. They count towards learning_starts."""
        return self.memories.add_prior(
            observations, normalized_actions, rewards, next_observations, terminated, pixels, next_pixels
        )

    def count_step(
        self,
        obs,
        action,
        reward: float,
        next_obs,
        terminated: bool,
        advised: bool = False,
        success: Optional[bool] = None,
        store: bool = True,
    ) -> None:
        """The storing half of step(): the transition into D (and D_advising when advised) and
        into the episode's statistics, without updates or the episode's end. For callers that
        update elsewhere (stacked seeds update many learners at once)."""
        normalized = self.normalize(action)
        if store:
            self.store(obs, normalized, reward, next_obs, terminated, advised)
        else:
            self.memories.check(obs, normalized, reward, next_obs)

        self._episode_return += float(reward)
        self.episode_step += 1
        self.tally.total_steps += 1
        self.success.update(self.observation.state(next_obs), float(reward))
        if success is not None:
            self._reported_success = bool(success)

    @property
    def ready_to_learn(self) -> bool:
        """D holds learning_starts transitions: every step from now on updates."""
        return self.memories.ready()

    def step(
        self,
        obs,
        action,
        reward: float,
        next_obs,
        terminated: bool,
        truncated: bool,
        advised: bool = False,
        success: Optional[bool] = None,
        learn: bool = True,
    ) -> Optional[EpisodeSummary]:
        """Store (s_t, a_t, r_t, s_{t+1}) in D, and in D_advising when advised; update.

        Returns the episode's summary when this transition ended it. A non-finite or
        wrongly sized transition raises ValueError and changes nothing. ``success``: the
        env's own verdict, where it reports one; the last one given in an episode decides
        its success over the learner's criterion. ``learn=False`` (an actor node, whose
        trainer learns elsewhere): the transition is checked and counted in the episode, not
        stored and not learned from.
        """
        self.count_step(obs, action, reward, next_obs, terminated, advised, success, store=learn)
        if learn:
            updates_after_a_step(self.config, self.ready_to_learn, lambda: self.update(next_obs))
        if terminated or truncated:
            return self.end_episode()
        return None

    def update(self, next_obs=None) -> dict:
        """One gradient update (updater.py): batches from D and D_advising, then algorithm1_update;
        compiled, it then acts ahead on ``next_obs``, the observation expected next (acting_ahead.py)."""
        batch, advice = self.memories.sample()
        ahead = next_obs is not None and self.updater.acts_ahead  # (else its tensor would be made for nothing)
        return self.updater.update(batch, advice, self.observation.tensor(next_obs) if ahead else None)

    def start_compiling(self, background: bool = True):
        """compile_update now (updater.py); returns the CompiledUpdate, or None where refused."""
        return self.updater.start_compiling(background)

    # ------------------------------------------------------------------ episodes

    def _reset_episode(self) -> None:
        self.memories.episode_ended()  # a camera's next frame opens an episode in D
        self.episode_step = 0
        self.episode_interrupted = False
        self._episode_return = 0.0
        self._episode_advice = AdviceCounts()
        self._episode_stops, self._episode_stopped_s = 0, 0.0
        self._reported_success = None
        self.success.reset()

    def end_episode(self) -> EpisodeSummary:
        """Close the current episode: its summary, then the next episode index."""
        counts = self._episode_advice
        success = (
            self.success.success(self._episode_return) if self._reported_success is None else self._reported_success
        )
        summary = EpisodeSummary(
            episode=self.episode,
            episode_return=self._episode_return,
            length=self.episode_step,
            **counts.summary_fields(),
            success=bool(success) and not self.episode_interrupted,
            total_steps=self.total_steps,
            alpha=self.alpha,
            interrupted=self.episode_interrupted,
            stops=self._episode_stops,
            stopped_s=self._episode_stopped_s,
        )
        row = self.tally.close(summary, counts)
        self._reset_episode()
        return row

    def abandon_episode(self) -> None:
        """Drop the current episode's statistics without a summary (e.g. the env stalled).

        Its transitions stay in the replay memory; the episode index is reused, so the
        per-episode record has neither a gap nor a bogus entry.
        """
        self._reset_episode()

    def mark_interrupted(self) -> None:
        """The caller did not see all of the current episode (a lost step, a mid-episode start):
        its summary will say so, and never count it as a success."""
        self.episode_interrupted = True
        self.memories.episode_ended()  # a camera's frames before the gap belong to no stack after it

    def note_stopped(self, seconds: float, starts: bool = True) -> None:
        """The person's STOP held the current episode for ``seconds`` (``starts``: one more press).
        The episode is paused, not abandoned: its summary says how long."""
        self._episode_stops += int(starts)
        self._episode_stopped_s += max(0.0, float(seconds))

    # ------------------------------------------------------------------ state

    def state_dict(self) -> dict:
        """Everything needed to resume, as tensors and plain Python values only."""
        return {
            'config': self.config.to_dict(),
            'obs_dim': self.obs_dim,
            'action_low': self.scaler.low.tolist(),
            'action_high': self.scaler.high.tolist(),
            'actor': self.actor.state_dict(),
            'critic': self.critic.state_dict(),
            'critic_target': self.critic_target.state_dict(),
            **self._camera_state(),
            **self.updater.state_dict(),
            'gates': self.gates.state_dict(),
            'counters': {
                'episode': self.episode,
                'total_steps': self.total_steps,
                'updates': self.updates,
                'advice_total': self.advice_total.to_dict(),
            },
            'rng': self.streams.state_dict(),
        }

    def _camera_state(self) -> dict:
        """A camera's part of the state: its sizes and the encoder's weights (none for a vector)."""
        observation = self.observation
        if observation.camera is None or observation.encoder is None:
            return {}
        return {'camera': dataclasses.asdict(observation.camera), 'encoder': observation.encoder.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        """Restore from ``state_dict()``. Validates first: on any error the learner is unchanged."""
        check_state(state)
        check_camera(state, self.observation.camera)
        if int(state['obs_dim']) != self.obs_dim or len(state['action_low']) != self.action_dim:
            raise ValueError(
                f'checkpoint is for observations of {state["obs_dim"]} and actions of '
                f'{len(state["action_low"])} values; this learner has {self.obs_dim} and {self.action_dim}'
            )
        saved_hidden = tuple(state['config'].get('hidden', ()))
        if saved_hidden != self.config.hidden:
            raise ValueError(f'checkpoint has hidden layers {saved_hidden}, this learner {self.config.hidden}')

        # Load into copies, then swap, so that a failure half-way changes nothing.
        actor, critic, critic_target = (copy.deepcopy(m) for m in (self.actor, self.critic, self.critic_target))
        actor.load_state_dict(state['actor'])
        critic.load_state_dict(state['critic'])
        critic_target.load_state_dict(state['critic_target'])
        encoder = copy.deepcopy(self.observation.encoder)
        if encoder is not None:
            encoder.load_state_dict(state['encoder'])
        log_alpha, optimizers = self.updater.loaded_parts(state, actor, critic, encoder)
        gates = copy.deepcopy(self.gates)
        gates.load_state_dict(state['gates'])
        gates.budget = self.budget
        counters = state['counters']
        advice_total = AdviceCounts.from_dict(counters['advice_total'])
        streams = self.streams.loaded(state['rng'])

        self.policy.actor = actor
        self.critics.critic, self.critics.critic_target = critic, critic_target
        if encoder is not None:
            self.observation.encoder = encoder
        self.updater.adopt(log_alpha, optimizers, int(counters['updates']))
        self.gates = gates
        self.streams.adopt(streams)  # the parts hold this RandomStreams
        self.tally = RunTally(int(counters['episode']), int(counters['total_steps']), advice_total)
        # The settings a person may change while the run goes on (the budgets) come back as they
        # were at the save: a resumed run keeps the budget set on the page or with ros2 param set.
        self.resumed_changes = resumed_changes(state['config'], self.config)
        for name in resumed_settings(state['config']):
            setattr(self.config, name, check_value(name, state['config'][name]))
        self._reset_episode()
