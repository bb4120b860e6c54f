"""The advising gates of EQ-HRL (Section 3.1, 3.2): dynamic thresholds and the early-advising budget."""

from __future__ import annotations

import dataclasses
import math
import random
import statistics
from collections import deque
from dataclasses import dataclass
from typing import Iterable, Optional

from . import equations as eq
from .advice_window import AdviceBudget
from .config import EXTENSION_MODES, SCORE_MODES, LearnerConfig, check_value


def step_patterns(flat: tuple) -> list:
    """random_ask_steps as [(length, steps)] per episode, or ValueError naming what is wrong."""
    patterns, block = [], []
    for value in flat:
        if value != -1:
            block.append(value)
            continue
        if not block or block[0] < 1:
            raise ValueError(f'random_ask_steps: each episode starts with its length (>= 1), found {block[:1]}')
        length, steps = block[0], block[1:]
        if any(not 0 <= s < length for s in steps) or len(set(steps)) != len(steps):
            raise ValueError(f'random_ask_steps: the steps of an episode of {length} are distinct, in [0, {length})')
        patterns.append((length, tuple(steps)))
        block = []
    if block:
        raise ValueError('random_ask_steps: the last episode is not ended by -1')
    return patterns


def place_owed(placed: set, owed: list, length: int, offset: int) -> set:
    """``placed`` with the ``owed`` steps added as one block (their gaps kept) moved round
    ``length`` by ``offset``; a step already taken moves to the next free one. Owed requests
    beyond the episode's free steps are dropped (they would need more steps than it has)."""
    placed = set(placed)
    for s in owed:
        if len(placed) >= length:
            break
        place = (s - owed[0] + offset) % length
        while place in placed:
            place = (place + 1) % length
        placed.add(place)
    return placed


class FifoQueue:
    """A fixed-length FIFO of recent values (D_queue or E_queue of Section 3.2)."""

    def __init__(self, length: int, values: Iterable[float] = ()):
        if length < 1:
            raise ValueError(f'queue length must be >= 1, got {length}')
        self._length = int(length)
        self._values: deque[float] = deque((float(v) for v in values), maxlen=length)

    @property
    def length(self) -> int:
        return self._length

    def full(self) -> bool:
        return len(self._values) == self._length

    def push(self, value: float) -> None:
        self._values.append(float(value))  # the oldest value falls out once full

    def values(self) -> list[float]:
        return list(self._values)

    def __len__(self) -> int:
        return len(self._values)


@dataclass(frozen=True)
class GateDecision:
    """What the gates said at one step. ``fire`` means: ask the expert now."""

    fire: bool
    within_budget: bool  # Eq. 7 (and a mode that asks at all)
    queues_ready: bool = False  # each queue holds queue_length earlier values (dynamic thresholds)
    ask: bool = False  # Eq. 10 left (or D(s) > fixed threshold)
    respond: bool = False  # Eq. 10 right (or E(s) < fixed threshold)
    discrepancy: float = float('nan')  # D(s), Eq. 8; NaN when not evaluated
    entropy: float = float('nan')  # E(s), Eq. 9; NaN when not evaluated
    d_threshold: float = float('nan')  # max(D_queue) before the push, or the fixed threshold
    e_threshold: float = float('nan')  # min(E_queue) before the push, or the fixed threshold
    # modes joint_rank, novelty, advice_gain: the rank (for joint_rank, the rank product of D(s)
    # and E(s)) and the threshold it was held against; novelty, advice_gain: the score ranked
    joint_rank: float = float('nan')
    joint_threshold: float = float('nan')
    score: float = float('nan')
    refractory: bool = False  # the gates fired, but a request of this episode was too few steps ago

    @property
    def reason(self) -> str:
        """Why the gates fired or not, in words (made only when someone reads it)."""
        if not self.within_budget:
            return "outside the advising budget (Eq. 7) or the person's seconds, or mode sac"
        if self.refractory:
            return 'the gates fired, but a request was made too few steps ago (request_refractory_steps)'
        if not self.queues_ready:
            return 'queues filling'
        has_d, has_e = not math.isnan(self.discrepancy), not math.isnan(self.entropy)
        if not math.isnan(self.score):  # modes novelty, advice_gain
            relation = '>=' if self.fire else '<'
            return f'score {self.score:.3f} ranks {self.joint_rank:.3f} {relation} threshold {self.joint_threshold:.3f}'
        if not math.isnan(self.joint_rank):  # mode joint_rank
            relation = '>=' if self.fire else '<'
            return f'rank product {self.joint_rank:.3f} {relation} threshold {self.joint_threshold:.3f}'
        if not (has_d or has_e):  # mode random
            return 'a random draw chose this step' if self.fire else 'the random draw said no'
        if has_d and self.ask and not has_e and not self.fire:  # mode ask_random
            return 'D(s) > threshold, but the random draw said no'
        if self.fire:
            return ' and '.join([*(['D(s) > threshold'] if has_d else []), *(['E(s) < threshold'] if has_e else [])])
        if has_d and not self.ask:
            return 'D(s) <= threshold: the critics agree'
        return 'E(s) >= threshold: the policy is not sure'


class AdvisingGates:
    """Decides, step by step, whether the learner asks the expert (Algorithm 1's if-condition).

    - ``sac``: never asks.
    - ``qasac``: asks when D(s) > max(D_queue) (the ask gate only).
    - ``eqsac``: asks when D(s) > max(D_queue) and E(s) < min(E_queue).
    - ``respond`` (ablation): asks when E(s) < min(E_queue) (the respond gate only).
    - ``random`` (baseline): asks when a uniform draw is below ``random_ask_rate``: as many
      requests as a gate that fires at that rate, at states chosen by chance. With
      ``random_ask_schedule``, exactly schedule[e] requests in episode e (while it lasts), at
      steps drawn uniformly among its first ``random_ask_horizon``: a baseline matched to
      another run episode by episode, so that it asks when that run asked, at other states.
      With ``random_ask_steps`` (an extension), matched step by step: each episode asks at the
      steps the other run asked at, moved round the episode's length by a random offset, so the
      count, the gaps between requests and their runs are that run's, the place is chance's;
      requests at steps this run's episode ended before are owed to its next episode.
    - ``ask_random`` (baseline): asks when D(s) > max(D_queue) and a uniform draw is below
      ``random_ask_rate``: the ask gate thinned at random, where EQSAC thins it by E(s).
    Extensions beyond the paper (labelled so in every table):
    - ``ask_median``: asks when D(s) > max(D_queue) and E(s) < median(E_queue): the ask gate
      thinned by a softer respond gate.
    - ``joint_rank``: asks when rank_D * rank_E >= a threshold, where rank_D is the share of
      D_queue below D(s) and rank_E the share of E_queue above E(s) (both 1 exactly when EQSAC
      fires); the threshold starts at 1 (EQSAC's rule, with >= for >) and moves by
      ``gate_threshold_step`` per step toward asking at ``gate_target_rate`` (Robbins-Monro).
    - ``novelty`` and ``advice_gain``: a score of the state (core/algorithm/state_scores.py),
      ranked in a queue of its own as joint_rank ranks, against a threshold tuned the same way;
      advice_gain asks by chance at gate_target_rate until it has enough answers to score from.
    All only while episode < advising_budget (Eq. 7).

    Dynamic thresholds compare the current value with the queue *as it was before
    this step*, then push it; a gate stays closed until its queue holds ``queue_length``
    earlier values. The queues run across episode boundaries. Fixed thresholds
    (``threshold_kind='fixed'``) compare with constants instead.
    """

    def __init__(
        self,
        mode: str,
        advising_budget: int | AdviceBudget,
        queue_length: int = 15,
        threshold_kind: str = 'dynamic',
        fixed_d_threshold: float = 1.0,
        fixed_e_threshold: float = 0.0,
        random_ask_rate: float = 0.0,
        random_ask_schedule: tuple = (),
        random_ask_horizon: int = 200,
        gate_target_rate: float = 0.015,
        gate_threshold_step: float = 0.01,
        random_ask_steps: tuple = (),
        request_refractory_steps: int = 0,
        score_queue_length: int = 200,
    ):
        # The rules of each value live with LearnerConfig's fields (core/algorithm/config.py).
        self.mode = check_value('mode', mode)
        check_value('threshold_kind', threshold_kind)
        # The budget is the learner's (advice_window.py, its one home); gates made on their own
        # (tests, tools) get one of their own.
        if isinstance(advising_budget, AdviceBudget):
            self.budget = advising_budget
        else:
            self.budget = AdviceBudget(LearnerConfig(mode=self.mode, advising_budget=advising_budget))
        self.threshold_kind = threshold_kind
        if mode in EXTENSION_MODES and threshold_kind != 'dynamic':
            raise ValueError(f'mode {mode} ranks D(s) and E(s) within their queues: it needs threshold_kind dynamic')
        self.fixed_d_threshold = float(fixed_d_threshold)
        self.fixed_e_threshold = float(fixed_e_threshold)
        self.random_ask_rate = check_value('random_ask_rate', random_ask_rate)
        self.random_ask_schedule = check_value('random_ask_schedule', random_ask_schedule)
        self.random_ask_horizon = check_value('random_ask_horizon', random_ask_horizon)
        self._scheduled_episode, self._scheduled_asked = -1, 0  # requests made so far in that episode
        self.step_patterns = step_patterns(check_value('random_ask_steps', random_ask_steps))
        self._shifted_episode = -1
        self._shifted_steps: frozenset[int] = frozenset()  # the steps to ask at in that episode
        self._shifted_reached = -1  # the last step of that episode the gates saw
        self.request_refractory_steps = check_value('request_refractory_steps', request_refractory_steps)
        self._last_request = (-1, 0)  # (episode, step) of the last request made
        self.gate_target_rate = check_value('gate_target_rate', gate_target_rate)
        self.gate_threshold_step = check_value('gate_threshold_step', gate_threshold_step)
        self.joint_threshold = 1.0  # mode joint_rank: starts at EQSAC's rule
        self.d_queue = FifoQueue(queue_length)
        self.e_queue = FifoQueue(queue_length)
        self.s_queue = FifoQueue(score_queue_length)  # modes novelty, advice_gain: their scores

    @property
    def advising_budget(self) -> int:
        return self.budget.episodes

    @property
    def uses_discrepancy(self) -> bool:
        return self.mode in ('qasac', 'eqsac', 'ask_random', 'ask_median', 'joint_rank')

    @property
    def uses_entropy(self) -> bool:
        return self.mode in ('eqsac', 'respond', 'ask_median', 'joint_rank')

    @property
    def uses_draw(self) -> bool:
        return self.mode in ('random', 'ask_random', 'advice_gain')

    @property
    def uses_score(self) -> bool:
        return self.mode in SCORE_MODES

    def needs_evaluation(self, episode: int) -> bool:
        """Whether D(s), E(s) or the random draw are needed this step (skipped when they cannot matter)."""
        return self.budget.within_episodes(episode)

    def decide(
        self, episode: int, discrepancy=None, entropy=None, draw=None, step: int = 0, score=None
    ) -> GateDecision:
        """Whether to ask now (_decide: the mode's rule; ``score``: the state's, for novelty and
        advice_gain, None while it cannot be scored yet), then request_refractory_steps (an
        extension): no request within that many steps after the last one of the episode."""
        if self.uses_score and self.budget.within_episodes(episode):
            decision = self._scored(score, draw)
        else:
            decision = self._decide(episode, discrepancy, entropy, draw, step)
        if not decision.fire:
            return decision
        last_episode, last_step = self._last_request
        if (
            self.request_refractory_steps
            and last_episode == episode
            and step - last_step <= self.request_refractory_steps
        ):
            return dataclasses.replace(decision, fire=False, refractory=True)
        self._last_request = (episode, step)
        return decision

    def _decide(
        self,
        episode: int,
        discrepancy: float | None = None,
        entropy: float | None = None,
        draw: float | None = None,
        step: int = 0,
    ) -> GateDecision:
        """``discrepancy`` D(s) where uses_discrepancy, ``entropy`` E(s) where uses_entropy,
        ``draw`` (uniform in [0, 1)) where uses_draw; each needed only inside the budget.
        ``step``: the step's index in its episode (random_ask_schedule spreads over it)."""
        if not self.budget.within_episodes(episode):
            return GateDecision(False, within_budget=False)
        if (
            (self.uses_discrepancy and discrepancy is None)
            or (self.uses_entropy and entropy is None)
            or (self.uses_draw and draw is None)
        ):
            raise ValueError(f'mode {self.mode} needs D(s), E(s) or its draw inside the budget')
        # What the mode does not use is NaN from here on (never compared: the uses_* guards).
        discrepancy = math.nan if discrepancy is None else float(discrepancy)
        entropy = math.nan if entropy is None else float(entropy)
        if self.mode == 'random':
            return GateDecision(
                self._random_request(episode, step, float(draw or 0.0)), within_budget=True, queues_ready=True
            )

        if self.threshold_kind == 'fixed':
            d_threshold, e_threshold = self.fixed_d_threshold, self.fixed_e_threshold
            ask = discrepancy > d_threshold if self.uses_discrepancy else True
            respond = entropy < e_threshold if self.uses_entropy else True
            d_ready = e_ready = True
        else:
            d_ready = self.d_queue.full() or not self.uses_discrepancy
            e_ready = self.e_queue.full() or not self.uses_entropy
            d_values = self.d_queue.values()
            e_values = self.e_queue.values()
            d_threshold = max(d_values) if d_values else float('nan')
            e_threshold = min(e_values) if e_values else float('nan')
            if self.mode == 'ask_median' and e_values:
                e_threshold = statistics.median(e_values)
            ask = (not self.uses_discrepancy) or (d_ready and eq.ask_condition(discrepancy, d_values))
            if self.mode == 'ask_median':
                respond = e_ready and entropy < e_threshold
            else:
                respond = (not self.uses_entropy) or (e_ready and eq.respond_condition(entropy, e_values))
            if self.mode == 'joint_rank' and d_ready and e_ready:
                return self._joint_rank(discrepancy, entropy, d_values, e_values, ask, respond)
            # Push after comparing: the current value never raises its own threshold.
            if self.uses_discrepancy:
                self.d_queue.push(discrepancy)
            if self.uses_entropy:
                self.e_queue.push(entropy)

        if self.mode == 'ask_random':
            respond = draw < self.random_ask_rate  # chance in place of the respond gate
        fire = ask and respond and self.mode != 'joint_rank'  # joint_rank with a queue filling: no
        return GateDecision(
            fire=fire,
            within_budget=True,
            queues_ready=d_ready and e_ready,
            ask=ask if self.uses_discrepancy else False,
            respond=respond if self.uses_entropy else False,
            discrepancy=float(discrepancy) if discrepancy is not None else float('nan'),
            entropy=float(entropy) if entropy is not None else float('nan'),
            d_threshold=d_threshold if self.uses_discrepancy else float('nan'),
            e_threshold=e_threshold if self.uses_entropy else float('nan'),
        )

    def _joint_rank(self, discrepancy, entropy, d_values, e_values, ask, respond) -> GateDecision:
        rank_d = sum(v < discrepancy for v in d_values) / len(d_values)
        rank_e = sum(v > entropy for v in e_values) / len(e_values)
        joint, threshold = rank_d * rank_e, self.joint_threshold
        fire = joint >= threshold
        # Robbins-Monro: up when it asked, down when it did not, so that it asks at the target rate.
        step = self.gate_threshold_step * (float(fire) - self.gate_target_rate)
        self.joint_threshold = min(1.0, max(0.0, threshold + step))
        self.d_queue.push(discrepancy)
        self.e_queue.push(entropy)
        return GateDecision(
            fire=fire,
            within_budget=True,
            queues_ready=True,
            ask=ask,
            respond=respond,
            discrepancy=float(discrepancy),
            entropy=float(entropy),
            d_threshold=max(d_values),
            e_threshold=min(e_values),
            joint_rank=joint,
            joint_threshold=threshold,
        )

    def _scored(self, score: Optional[float], draw: Optional[float]) -> GateDecision:
        """novelty, advice_gain: the score's rank among the queue's, against a threshold that
        starts at 1 (above every queued score, as the ask gate) and moves toward gate_target_rate."""
        if score is None:  # nothing to score from yet: advice_gain asks by chance, novelty waits
            fire = self.mode == 'advice_gain' and draw is not None and draw < self.gate_target_rate
            return GateDecision(fire, within_budget=True, queues_ready=False)
        values, threshold = self.s_queue.values(), self.joint_threshold
        ready = self.s_queue.full()
        rank = sum(v < score for v in values) / len(values) if values else 0.0
        fire = ready and rank >= threshold
        if ready:  # Robbins-Monro, as joint_rank
            step = self.gate_threshold_step * (float(fire) - self.gate_target_rate)
            self.joint_threshold = min(1.0, max(0.0, threshold + step))
        self.s_queue.push(float(score))
        return GateDecision(
            fire, within_budget=True, queues_ready=ready, joint_rank=rank, joint_threshold=threshold, score=float(score)
        )

    def _random_request(self, episode: int, step: int, draw: float) -> bool:
        if self.step_patterns:
            return self._shifted_request(episode, step, draw)
        if not self.random_ask_schedule:
            return draw < self.random_ask_rate
        if episode != self._scheduled_episode:
            self._scheduled_episode, self._scheduled_asked = episode, 0
        wanted = self.random_ask_schedule[episode] if episode < len(self.random_ask_schedule) else 0
        left = wanted - self._scheduled_asked
        # Selection sampling (Knuth's Algorithm S): ask with chance left / steps left, which
        # places the requests at a uniformly random set of steps of the horizon.
        fire = left > 0 and draw * max(1, self.random_ask_horizon - step) < left
        self._scheduled_asked += int(fire)
        return fire

    def _shifted_request(self, episode: int, step: int, draw: float) -> bool:
        """random_ask_steps: the episode's pattern moved round its length by an offset drawn with
        the episode's first draw (the same count, gaps and runs, at a random place). Requests at
        steps this arm's episode ended before reaching (its episodes end elsewhere than the
        reference's) are owed: the next episode of the pattern asks them too, as a block with
        their gaps moved round its length by a second random offset, so the run's count holds."""
        if episode != self._shifted_episode:
            owed = sorted(s for s in self._shifted_steps if s > self._shifted_reached)
            self._shifted_episode, self._shifted_steps, self._shifted_reached = episode, frozenset(), -1
            if episode < len(self.step_patterns):
                length, steps = self.step_patterns[episode]
                offset = min(int(draw * length), length - 1)
                placed = {(s + offset) % length for s in steps}
                if owed:  # a second offset from the same draw's bits: no stream of its own to keep
                    placed = place_owed(placed, owed, length, random.Random(int(draw * 2**53)).randrange(length))
                self._shifted_steps = frozenset(placed)
        self._shifted_reached = max(self._shifted_reached, step)
        return step in self._shifted_steps

    def state_dict(self) -> dict:
        return {
            'd_queue': self.d_queue.values(),
            'e_queue': self.e_queue.values(),
            'joint_threshold': self.joint_threshold,
            's_queue': self.s_queue.values(),
            'shifted': [self._shifted_episode, self._shifted_reached, sorted(self._shifted_steps)],
        }

    def load_state_dict(self, state: dict) -> None:
        length = self.d_queue.length
        self.d_queue = FifoQueue(length, state['d_queue'])
        self.e_queue = FifoQueue(length, state['e_queue'])
        self.joint_threshold = float(state.get('joint_threshold', 1.0))  # absent before the extension
        self.s_queue = FifoQueue(self.s_queue.length, state.get('s_queue', ()))  # absent before novelty and advice_gain
        # random_ask_steps: the episode in flight and what it owes (absent before owed requests)
        episode, reached, steps = state.get('shifted', (-1, -1, ()))
        self._shifted_episode, self._shifted_reached = int(episode), int(reached)
        self._shifted_steps = frozenset(int(s) for s in steps)


def gates_for(config: LearnerConfig, budget: AdviceBudget) -> AdvisingGates:
    """The gates that ``config`` asks for, over ``budget``."""
    cfg = config
    return AdvisingGates(
        cfg.mode,
        budget,
        cfg.queue_length,
        cfg.threshold_kind,
        cfg.fixed_d_threshold,
        cfg.fixed_e_threshold,
        cfg.random_ask_rate,
        cfg.random_ask_schedule,
        cfg.random_ask_horizon,
        cfg.gate_target_rate,
        cfg.gate_threshold_step,
        cfg.random_ask_steps,
        cfg.request_refractory_steps,
        cfg.gate_score_queue,
    )
