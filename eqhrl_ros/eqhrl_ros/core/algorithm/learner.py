"""EQSACLearner: SAC, QASAC and EQSAC in one class (Algorithm 1 of the paper).

One step of Algorithm 1, as the caller drives it:

    proposal = learner.propose(obs)                  # a_t ~ pi(.|s_t); D(s), E(s); the gates
    if proposal.decision.fire:                       # Eq. 7 and Eq. 10
        action, advised = learner.resolve_advice(proposal, expert(proposal.request)).action_and_advised()
    else:
        action, advised = proposal.action, False
    next_obs, reward, terminated, truncated, _ = env.step(action)
    summary = learner.step(obs, action, reward, next_obs, terminated, truncated, advised)
                                                     # store in D (and D_advising); update()

The caller may be a plain loop (core/runs/in_process.py) or a ROS node; the learner never
knows who answers advice. Every equation it uses lives in core/algorithm/equations.py.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch

from ..data.advice import FAILURE_KINDS, Advice, AdviceRequest, check_advised_action
from ..data.replay import ReplayBuffer, checked_transition
from ..data.summary import EpisodeSummary
from ..envs.spec import ActionScaler, SuccessCriterion
from . import equations as eq
from .advising import AdvisingGates, GateDecision
from .config import LearnerConfig, asks_for_advice, check_value
from .networks import SquashedGaussianActor, TwinCritic
from .update import algorithm1_update, refusal, update_noise


@dataclass(frozen=True)
class Proposal:
    """The learner's own action for s_t, the gate decision, and the request to send if it fired."""

    action: np.ndarray  # env units
    decision: GateDecision
    request: Optional[AdviceRequest]


@dataclass(frozen=True)
class Resolution:
    """How an advice request ended: the action to take, and why."""

    action: np.ndarray  # env units: the advice, or the learner's own action
    advised: bool  # the advice is used (and goes to D_advising)
    outcome: str  # 'given', 'declined' or 'failed'
    detail: str = ''  # the failure kind, or the expert's reason for declining

    def action_and_advised(self) -> tuple[np.ndarray, bool]:
        """(action, advised): what Algorithm 1 acts with and stores."""
        return self.action, self.advised


# EpisodeSummary's advice fields and the AdviceCounts they come from: one mapping, both ways.
SUMMARY_FIELDS = {
    'advice_asked': 'asked',
    'advice_given': 'given',
    'advice_human': 'human',
    'advice_declined': 'declined',
    'human_time_s': 'human_time_s',
    'takeovers': 'takeovers',
    'takeover_steps': 'takeover_steps',
    'takeover_s': 'takeover_s',
}


@dataclass
class AdviceCounts:
    asked: int = 0
    given: int = 0
    human: int = 0  # of the given advice, how much came from a person
    declined: int = 0
    failed: dict = field(default_factory=lambda: {kind: 0 for kind in FAILURE_KINDS})
    # Seconds a person spent on requests: answering, skipping, or a whole answer window let pass.
    human_time_s: float = 0.0
    # Steps the person took over unasked (mixed initiative): stretches of them, steps, seconds.
    takeovers: int = 0
    takeover_steps: int = 0
    takeover_s: float = 0.0

    @property
    def failed_total(self) -> int:
        return sum(self.failed.values())

    def summary_fields(self) -> dict:
        """These counts as an EpisodeSummary's advice fields (failures as their total)."""
        return {
            **{field: getattr(self, name) for field, name in SUMMARY_FIELDS.items()},
            'advice_failed': self.failed_total,
        }

    @classmethod
    def from_summary(cls, summary: EpisodeSummary) -> 'AdviceCounts':
        """The counts an EpisodeSummary's advice fields hold (failures by kind stay with who counted them)."""
        return cls(**{name: getattr(summary, field) for field, name in SUMMARY_FIELDS.items()})

    def add(self, other: 'AdviceCounts') -> None:
        self.asked += other.asked
        self.given += other.given
        self.human += other.human
        self.declined += other.declined
        self.human_time_s += other.human_time_s
        self.takeovers += other.takeovers
        self.takeover_steps += other.takeover_steps
        self.takeover_s += other.takeover_s
        for kind, n in other.failed.items():
            self.failed[kind] += n

    def to_dict(self) -> dict:
        return {
            'asked': self.asked,
            'given': self.given,
            'human': self.human,
            'declined': self.declined,
            'failed': dict(self.failed),
            'human_time_s': self.human_time_s,
            'takeovers': self.takeovers,
            'takeover_steps': self.takeover_steps,
            'takeover_s': self.takeover_s,
        }

    @staticmethod
    def from_dict(d: dict) -> 'AdviceCounts':
        failed = {kind: 0 for kind in FAILURE_KINDS}
        failed.update({k: int(v) for k, v in d['failed'].items() if k in failed})
        return AdviceCounts(
            int(d['asked']),
            int(d['given']),
            int(d.get('human', 0)),
            int(d['declined']),
            failed,
            float(d.get('human_time_s', 0.0)),  # checkpoints before people were timed have none
            int(d.get('takeovers', 0)),  # nor before takeovers were counted
            int(d.get('takeover_steps', 0)),
            float(d.get('takeover_s', 0.0)),
        )


def learning_device(name: str) -> torch.device:
    """The torch device for LearnerConfig.device, or a ValueError that says what is missing."""
    if name == 'cuda' and not torch.cuda.is_available():
        raise ValueError(
            "device 'cuda' was asked for, but torch sees no GPU (torch.cuda.is_available() is False; "
            f'this torch is {torch.__version__}, and the CPU build has no CUDA); use device cpu'
        )
    return torch.device(name)


def adam(params, lr: float, state: dict | None = None) -> torch.optim.Adam:
    """Adam with its fused kernel: one pass over all of a network's tensors per step.

    On CPU the default Adam loops over tensors with several small ops each; the fused
    kernel is several times faster at Table 1's sizes (docs/performance.md). Same maths. A loaded
    ``state`` keeps its moments and step counts but not its implementation flags.
    """
    optimizer = torch.optim.Adam(params, lr=lr, fused=True)
    if state is not None:
        # A copy: torch's load_state_dict keeps the given moment and step tensors themselves, so
        # loading another live learner's state_dict() would have both step the same moments.
        optimizer.load_state_dict(copy.deepcopy(state))
        for group in optimizer.param_groups:
            group.update(fused=True, foreach=None)
    return optimizer


def adam_state(optimizer: torch.optim.Adam) -> tuple:
    """(exp_avgs, exp_avg_sqs, steps) of each parameter, the optimiser's own tensors; those it
    has not made yet (before its first step) made as torch's fused Adam makes them."""
    per = []
    for p in optimizer.param_groups[0]['params']:
        state = optimizer.state[p]
        if 'exp_avg' not in state:
            state['step'] = torch.zeros((), dtype=torch.float32, device=p.device)
            state['exp_avg'] = torch.zeros_like(p, memory_format=torch.preserve_format)
            state['exp_avg_sq'] = torch.zeros_like(p, memory_format=torch.preserve_format)
        per.append(state)
    return tuple([s[key] for s in per] for key in ('exp_avg', 'exp_avg_sq', 'step'))


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


def _check_state(state) -> None:
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
    for key in NETWORK_STATE:
        if any(t.is_floating_point() and not torch.isfinite(t).all() for t in _tensors(state.get(key))):
            raise ValueError(f"'{key}' holds non-finite values (NaN or inf)")
    for key in ('d_queue', 'e_queue'):
        values = state['gates'].get(key)
        if not isinstance(values, list) or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f'gates.{key} must be a list of finite numbers')
    threshold = state['gates'].get('joint_threshold', 1.0)
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not 0.0 <= threshold <= 1.0:
        raise ValueError(f'gates.joint_threshold must be a number in [0, 1], found {threshold!r}')


def resumed_settings(saved_config: dict) -> list:
    """The run-time (dynamic) LearnerConfig fields a checkpoint's config holds."""
    from .config import FIELDS

    return [name for name, f in FIELDS.items() if f.metadata['dynamic'] and name in saved_config]


class EQSACLearner:
    """Soft Actor-Critic with EQ-HRL advising gates and dual replay (SAC / QASAC / EQSAC)."""

    def __init__(
        self,
        obs_dim: int,
        action_low,
        action_high,
        config: LearnerConfig | None = None,
        success: SuccessCriterion | None = None,
    ):
        self.config = config or LearnerConfig()
        cfg = self.config
        if obs_dim < 1:
            raise ValueError(f'obs_dim must be >= 1, got {obs_dim}')
        self.obs_dim = int(obs_dim)
        self.scaler = ActionScaler(action_low, action_high)
        self.action_dim = self.scaler.dim
        self.success = success or SuccessCriterion()

        self.device = learning_device(cfg.device)
        # Networks are initialised from the seed without disturbing the caller's global RNG,
        # on the CPU: the same initial weights on every device.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(cfg.seed)
            self.actor = SquashedGaussianActor(self.obs_dim, self.action_dim, cfg.hidden).to(self.device)
            self.critic = TwinCritic(self.obs_dim, self.action_dim, cfg.hidden).to(self.device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.log_alpha = torch.tensor(math.log(cfg.initial_alpha), device=self.device, requires_grad=True)
        self.target_entropy = -float(self.action_dim)  # Table 1: target alpha = -action dim
        # The optimisers are made at the first update: torch imports its compiler
        # (torch._dynamo, over a second: docs/performance.md) when the first one is made,
        # which would otherwise delay the first env step by that much.
        self._optimizers_made = False
        # compile_update: made after the first eager update (compiled_update.py); None until then.
        self.compiled_update = None
        self._update_inputs = (None, None)  # update_inputs(): (the objects they came from, inputs)
        self._update_nets = None
        self.log = None  # the compiler's logger (info, warning); None: Python's; a node sets its own

        # One random stream per purpose, so that e.g. estimating E(s) never shifts
        # the noise of the policy's own actions. CPU generators on every device (noise()):
        # the same random numbers on a GPU as on the CPU.
        self.rng = {
            name: torch.Generator().manual_seed(cfg.seed + i)
            for i, name in enumerate(('act', 'update', 'replay', 'entropy', 'warmup', 'request'))
        }

        self.replay = ReplayBuffer(cfg.replay_capacity, self.obs_dim, self.action_dim)  # D
        self.advice_replay = ReplayBuffer(cfg.replay_capacity, self.obs_dim, self.action_dim)  # D_advising
        self.gates = AdvisingGates(
            cfg.mode,
            cfg.advising_budget,
            cfg.queue_length,
            cfg.threshold_kind,
            cfg.fixed_d_threshold,
            cfg.fixed_e_threshold,
            cfg.random_ask_rate,
            cfg.random_ask_schedule,
            cfg.random_ask_horizon,
            cfg.gate_target_rate,
            cfg.gate_threshold_step,
        )

        self.episode = 0  # index of the current episode: Eq. 7's "Iteration"
        self.episode_step = 0
        self.total_steps = 0
        self.updates = 0
        self.advice_total = AdviceCounts()
        self._reset_episode()

    # ------------------------------------------------------------------ acting

    @property
    def mode(self) -> str:
        return self.config.mode

    @property
    def alpha(self) -> float:
        return float(self.log_alpha.detach().exp())

    def noise(self, shape, stream: str, uniform: bool = False) -> torch.Tensor:
        """Standard normal (or uniform [0, 1)) noise from one of the learner's random streams, on its device."""
        draw = torch.rand if uniform else torch.randn
        return draw(shape, generator=self.rng[stream]).to(self.device)

    def _obs_tensor(self, obs) -> torch.Tensor:
        array = np.asarray(obs, dtype=np.float32).reshape(-1)
        if array.shape[0] != self.obs_dim:
            raise ValueError(f'observation has {array.shape[0]} values, the learner expects {self.obs_dim}')
        if not np.isfinite(array).all():
            raise ValueError('observation holds a non-finite value (NaN or inf)')
        return torch.from_numpy(array).unsqueeze(0).to(self.device)

    @torch.inference_mode()
    def act(self, obs, deterministic: bool = False) -> np.ndarray:
        """The policy's action in env units, without gates or counters (evaluation)."""
        mean, log_std = self.actor(self._obs_tensor(obs))
        if deterministic:
            return self.scaler.to_env(torch.tanh(mean)[0].cpu().numpy())
        noise = self.noise(mean.shape, 'act')
        return self.scaler.to_env(eq.squashed_gaussian_action(mean, log_std, noise)[0].cpu().numpy())

    @torch.inference_mode()
    def propose(self, obs) -> Proposal:
        """a_t ~ pi(.|s_t), then D(s) (Eq. 8), E(s) (Eq. 9) and the gates (Eq. 7, Eq. 10)."""
        obs_t = self._obs_tensor(obs)
        mean, log_std = self.actor(obs_t)
        if self.total_steps < self.config.random_warmup_steps:
            action = self.noise(mean.shape, 'warmup', uniform=True) * 2.0 - 1.0
        else:
            action = eq.squashed_gaussian_action(mean, log_std, self.noise(mean.shape, 'act'))

        if self.person_budget_left_s <= 0.0:  # the person's seconds are spent: as outside Eq. 7's budget
            decision = GateDecision(False, within_budget=False)
        elif self.gates.needs_evaluation(self.episode):
            discrepancy = entropy = draw = None
            if self.gates.uses_discrepancy:
                q1, q2 = self.critic(obs_t, action)
                discrepancy = float(eq.q_discrepancy(q1, q2))
            if self.gates.uses_entropy:
                if self.config.entropy_estimator == 'exact':
                    entropy = float(eq.policy_entropy(mean, log_std))
                else:
                    k_noise = self.noise((self.config.entropy_samples, *mean.shape), 'entropy')
                    entropy = float(eq.policy_entropy_monte_carlo(mean, log_std, k_noise))
            if self.gates.uses_draw:
                draw = float(torch.rand((), generator=self.rng['request']))
            decision = self.gates.decide(self.episode, discrepancy, entropy, draw, self.episode_step)
        else:
            decision = self.gates.decide(self.episode)

        env_action = self.scaler.to_env(action[0].cpu().numpy())
        request = None
        if decision.fire:
            request = AdviceRequest(
                observation=obs_t[0].cpu().numpy().copy(),
                proposed_action=env_action,
                action_low=self.scaler.low,
                action_high=self.scaler.high,
                discrepancy=decision.discrepancy,
                entropy=decision.entropy,
                episode=self.episode,
                step=self.episode_step,
            )
        return Proposal(env_action, decision, request)

    def resolve_advice(self, proposal: Proposal, advice: Advice | None = None, failure: str = '') -> Resolution:
        """Count the outcome of an advice request and return what to do.

        ``failure`` names why no answer came (one of experts.FAILURE_KINDS); otherwise
        ``advice`` is the answer. A refusal or a failure leaves the learner's own action.
        A person's time on the request (advice.response_time_s) is counted whatever they said;
        a person's answer window that passed (advice.timed_out) counts as a timeout.
        """
        counts = self._episode_advice
        counts.asked += 1
        if advice is not None and advice.human:
            counts.human_time_s += max(0.0, float(advice.response_time_s))
        if advice is not None and advice.timed_out:
            failure = 'timeout'
        if failure:
            if failure not in counts.failed:
                raise ValueError(f'unknown failure kind {failure!r}; one of {FAILURE_KINDS}')
            counts.failed[failure] += 1
            return Resolution(proposal.action, False, 'failed', failure)
        if advice is None or not advice.advised:
            counts.declined += 1
            return Resolution(proposal.action, False, 'declined', advice.reason if advice else '')
        action, failure = check_advised_action(advice.action, self.scaler.low, self.scaler.high)
        if failure:
            counts.failed[failure] += 1
            return Resolution(proposal.action, False, 'failed', failure)
        counts.given += 1
        counts.human += int(advice.human)
        return Resolution(action, True, 'given')

    def take_over(self, proposal: Proposal, action, seconds: float, starts: bool) -> Resolution:
        """The person took this step over unasked (mixed initiative): their action replaces the
        learner's, counted apart from answered requests (``starts``: a new stretch of takeover;
        ``seconds``: the person's time on this step). The step goes to D_advising too when
        takeover_to_advice_memory is set (as advice). An action outside the bounds is refused."""
        action, failure = check_advised_action(action, self.scaler.low, self.scaler.high)
        if failure:
            return Resolution(proposal.action, False, 'failed', failure)
        counts = self._episode_advice
        counts.takeovers += int(starts)
        counts.takeover_steps += 1
        counts.takeover_s += max(0.0, float(seconds))
        return Resolution(action, self.config.takeover_to_advice_memory, 'taken over')

    def set_advising_budget(self, episodes: int) -> None:
        """Change the early-advising budget (Eq. 7) while learning, e.g. from a person's console."""
        self.gates.advising_budget = self.config.advising_budget = check_value('advising_budget', episodes)

    def set_advising_budget_s(self, seconds: float) -> None:
        """Change the budget in the person's seconds (0: none) while learning."""
        self.config.advising_budget_s = check_value('advising_budget_s', seconds)

    @property
    def human_time_total_s(self) -> float:
        """The person's seconds on requests over the run so far, this episode's included."""
        return self.advice_total.human_time_s + self._episode_advice.human_time_s

    @property
    def person_budget_left_s(self) -> float:
        """Seconds of the person's budget left (inf when advising_budget_s is 0)."""
        budget = self.config.advising_budget_s
        return max(0.0, budget - self.human_time_total_s) if budget > 0 else float('inf')

    # ------------------------------------------------------------------ storing and learning

    def normalize(self, action) -> np.ndarray:
        """An action in env units as stored in D: mapped to [-1, 1] and clipped there."""
        return np.clip(self.scaler.to_normalized(action), -1.0, 1.0)

    def store(self, obs, normalized_action, reward: float, next_obs, terminated: bool, advised: bool) -> None:
        """(s_t, a_t, r_t, s_{t+1}) into D, and into D_advising when advised (QASAC, EQSAC).
        ``normalized_action`` in [-1, 1] (normalize()). A bad transition raises ValueError."""
        self.replay.add(obs, normalized_action, reward, next_obs, terminated)
        if advised and asks_for_advice(self.mode) and self.config.dual_replay:
            self.advice_replay.add(obs, normalized_action, reward, next_obs, terminated)

    def add_prior(self, observations, normalized_actions, rewards, next_observations, terminated) -> int:
        """Earlier runs' advised and person-initiated transitions, as prior data (RLPD, HIL-SERL):
        into D, and into D_advising where this mode has it, before the first step. Actions in
        [-1, 1]. They count towards learning_starts. Each row is checked as store() checks it
        (ValueError names the first bad one, and nothing of the call is kept after it)."""
        rows = 0
        for row in zip(observations, normalized_actions, rewards, next_observations, terminated):
            obs, action, reward, next_obs, done = row
            self.store(obs, np.clip(action, -1.0, 1.0), float(reward), next_obs, bool(done), advised=True)
            rows += 1
        return rows

    def record(
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
        update elsewhere (stacked_seeds.py updates many learners at once)."""
        normalized = self.normalize(action)
        if store:
            self.store(obs, normalized, reward, next_obs, terminated, advised)
        else:
            checked_transition(obs, normalized, reward, next_obs, self.obs_dim, self.action_dim)

        self._episode_return += float(reward)
        self.episode_step += 1
        self.total_steps += 1
        self.success.update(np.asarray(next_obs, dtype=np.float32), float(reward))
        if success is not None:
            self._reported_success = bool(success)

    @property
    def ready_to_learn(self) -> bool:
        """D holds learning_starts transitions: every step from now on updates."""
        return len(self.replay) >= self.config.learning_starts

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
        self.record(obs, action, reward, next_obs, terminated, advised, success, store=learn)
        if learn and self.ready_to_learn:
            for _ in range(self.config.updates_per_step):
                self.update()

        if terminated or truncated:
            return self.end_episode()
        return None

    def _make_optimizers(self) -> None:
        if not self._optimizers_made:
            cfg = self.config
            self.actor_optimizer = adam(self.actor.parameters(), cfg.actor_lr)
            self.critic_optimizer = adam(self.critic.parameters(), cfg.critic_lr)
            self.alpha_optimizer = adam([self.log_alpha], cfg.alpha_lr)
            self._optimizers_made = True

    def update(self) -> dict:
        """One gradient update: Algorithm 1's inner loop, algorithm1_update (update.py), compiled
        once compile_update has its program ready. The draws come first, in every path's order."""
        self._make_optimizers()
        batch, advice = self.sample_update_batches()
        noise = self.update_noise(batch, advice)
        weights, state, hyper = self.update_inputs()
        compiled = self.compiled_update
        function = compiled.function if compiled and compiled.ready else algorithm1_update
        losses = function(self.update_nets, weights, state, batch.fields(), advice and advice.fields(), noise, hyper)
        self.updates += 1
        info = {name: float(value) for name, value in losses.items()}
        info['alpha'] = self.alpha
        if self.config.compile_update and compiled is None:
            self.start_compiling()
        return info

    def sample_update_batches(self) -> tuple:
        """An update's batches: from D, and from D_advising (EQSAC and QASAC, Section 3.3; None
        while it is empty or in mode sac), sampled with replacement while it holds fewer than
        the batch asks for; ``advice_batch: proportional``: D_advising's share of the batch."""
        cfg = self.config
        batch = self.replay.sample(cfg.batch_size, self.rng['replay']).to(self.device)
        if not asks_for_advice(self.mode) or len(self.advice_replay) == 0:
            return batch, None
        size = cfg.batch_size
        if cfg.advice_batch == 'proportional':  # an ablation
            size = max(1, round(cfg.batch_size * len(self.advice_replay) / len(self.replay)))
        advice = self.advice_replay.sample(size, self.rng['replay'], replacement=len(self.advice_replay) < size)
        return batch, advice.to(self.device)

    def update_noise(self, batch, advice) -> tuple:
        """An update's noise from the 'update' stream, in the order every path draws it."""
        sizes = [len(batch.reward)] + ([len(advice.reward)] if advice is not None else [])
        return update_noise(
            lambda shape: self.noise(shape, 'update'), self.action_dim, sizes, self.config.actor_on_advice
        )

    def update_inputs(self) -> tuple:
        """(weights, Adam state, hyper) for algorithm1_update: views of the live weights and of
        the optimisers' own moments, which the update steps in place (so checkpoints save what it
        learned). Gathered again only when the learner replaced the objects that hold them
        (loading a checkpoint does) or the tensors behind them (stacked_seeds.py stacks and
        releases them); an optimiser without moments yet gets torch's initial ones."""
        owners = (
            self.actor,
            self.critic,
            self.critic_target,
            self.log_alpha,
            self.actor_optimizer,
            self.critic_optimizer,
            self.alpha_optimizer,
        )
        storage = tuple(p.data_ptr() for module in owners[:3] for p in module.parameters()) + (
            self.log_alpha.data_ptr(),
        )
        held, inputs = self._update_inputs
        if held is None or any(a is not b for a, b in zip(owners, held[0])) or storage != held[1]:
            weights = {
                'actor': {k: v.detach() for k, v in self.actor.named_parameters()},
                'critic': {k: v.detach() for k, v in self.critic.named_parameters()},
                'critic_target': {k: v.detach() for k, v in self.critic_target.named_parameters()},
                'log_alpha': self.log_alpha.detach(),
            }
            state, hyper = {}, {'gamma': self.config.gamma, 'tau': self.config.tau, 'seeds': 1}
            hyper['target_entropy'] = self.target_entropy
            for name in ('actor', 'critic', 'alpha'):
                optimizer = getattr(self, f'{name}_optimizer')
                state[name] = adam_state(optimizer)
                group = optimizer.param_groups[0]  # Adam's settings from the optimiser itself
                hyper[f'{name}_adam'] = {'lr': group['lr'], 'betas': tuple(group['betas']), 'eps': group['eps']}
            inputs = (weights, state, hyper)
            self._update_inputs = ((owners, storage), inputs)
        return inputs

    @property
    def update_nets(self) -> tuple:
        """The actor's and the twin critic's structure for algorithm1_update (copies: it gives
        them their weights, and must not touch the modules the learner acts with)."""
        if self._update_nets is None:
            self._update_nets = (copy.deepcopy(self.actor), copy.deepcopy(self.critic))
        return self._update_nets

    def start_compiling(self, background: bool = True):
        """compile_update: the whole update compiled in a background thread (compiled_update.py),
        from the optimisers' state after an eager update; a configuration that cannot be compiled
        stays eager, said in one log line. Returns the CompiledUpdate (or None)."""
        from .compiled_update import LOG, CompiledUpdate

        why = refusal(self.config, 'compiled')
        if why:
            self.compiled_update = False  # asked once, refused once
            (self.log or LOG).warning(f'compile_update: {why}; the learner stays with the eager update')
            return None
        self._make_optimizers()
        self.compiled_update = CompiledUpdate(self, log=self.log, background=background)
        return self.compiled_update

    # ------------------------------------------------------------------ episodes

    def _reset_episode(self) -> None:
        self.episode_step = 0
        self.episode_interrupted = False
        self._episode_return = 0.0
        self._episode_advice = AdviceCounts()
        self._episode_stops, self._episode_stopped_s = 0, 0.0
        self._reported_success: Optional[bool] = None
        self.success.reset()

    def end_episode(self) -> EpisodeSummary:
        """Close the current episode: its summary, then the next episode index."""
        counts = self._episode_advice
        summary = EpisodeSummary(
            episode=self.episode,
            episode_return=self._episode_return,
            length=self.episode_step,
            **counts.summary_fields(),
            success=bool(
                self.success.success(self._episode_return) if self._reported_success is None else self._reported_success
            )
            and not self.episode_interrupted,
            total_steps=self.total_steps,
            alpha=self.alpha,
            interrupted=self.episode_interrupted,
            human_time_total_s=self.advice_total.human_time_s + counts.human_time_s,
            stops=self._episode_stops,
            stopped_s=self._episode_stopped_s,
        )
        self.advice_total.add(counts)
        self.episode += 1
        self._reset_episode()
        return summary

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

    def note_stopped(self, seconds: float, starts: bool = True) -> None:
        """The person's STOP held the current episode for ``seconds`` (``starts``: one more press).
        The episode is paused, not abandoned: its summary says how long."""
        self._episode_stops += int(starts)
        self._episode_stopped_s += max(0.0, float(seconds))

    @property
    def episode_advice(self) -> AdviceCounts:
        return self._episode_advice

    # ------------------------------------------------------------------ state

    def state_dict(self) -> dict:
        """Everything needed to resume, as tensors and plain Python values only."""
        self._make_optimizers()
        return {
            'config': self.config.to_dict(),
            'obs_dim': self.obs_dim,
            'action_low': self.scaler.low.tolist(),
            'action_high': self.scaler.high.tolist(),
            'actor': self.actor.state_dict(),
            'critic': self.critic.state_dict(),
            'critic_target': self.critic_target.state_dict(),
            'log_alpha': self.log_alpha.detach().clone(),
            'actor_optimizer': self.actor_optimizer.state_dict(),
            'critic_optimizer': self.critic_optimizer.state_dict(),
            'alpha_optimizer': self.alpha_optimizer.state_dict(),
            'gates': self.gates.state_dict(),
            'counters': {
                'episode': self.episode,
                'total_steps': self.total_steps,
                'updates': self.updates,
                'advice_total': self.advice_total.to_dict(),
            },
            'rng': {name: gen.get_state() for name, gen in self.rng.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore from ``state_dict()``. Validates first: on any error the learner is unchanged."""
        _check_state(state)
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
        log_alpha = state['log_alpha'].detach().clone().reshape(()).to(self.device).requires_grad_(True)
        cfg = self.config
        actor_opt = adam(actor.parameters(), cfg.actor_lr, state['actor_optimizer'])
        critic_opt = adam(critic.parameters(), cfg.critic_lr, state['critic_optimizer'])
        alpha_opt = adam([log_alpha], cfg.alpha_lr, state['alpha_optimizer'])
        gates = copy.deepcopy(self.gates)
        gates.load_state_dict(state['gates'])
        counters = state['counters']
        advice_total = AdviceCounts.from_dict(counters['advice_total'])
        rng = {name: torch.Generator() for name in self.rng}
        for name, gen in rng.items():
            if name in state['rng']:  # (a checkpoint from before a stream existed leaves it fresh)
                gen.set_state(state['rng'][name])
            else:
                gen.set_state(self.rng[name].get_state())

        self.actor, self.critic, self.critic_target = actor, critic, critic_target
        self.log_alpha = log_alpha
        self.actor_optimizer, self.critic_optimizer, self.alpha_optimizer = actor_opt, critic_opt, alpha_opt
        self._optimizers_made = True
        self.gates = gates
        self.rng = rng
        self.episode = int(counters['episode'])
        self.total_steps = int(counters['total_steps'])
        self.updates = int(counters['updates'])
        self.advice_total = advice_total
        # The settings a person may change while the run goes on (the budgets) come back as they
        # were at the save: a resumed run keeps the budget set on the page or with ros2 param set.
        for name in resumed_settings(state['config']):
            setattr(self.config, name, check_value(name, state['config'][name]))
        self.gates.advising_budget = self.config.advising_budget
        self._reset_episode()
