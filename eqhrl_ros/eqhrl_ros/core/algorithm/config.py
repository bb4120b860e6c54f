"""The learner's hyperparameters, each declared once: default, range or choices, description.

Everything else is derived from these fields: LearnerConfig's validation (here), the
learner node's ROS parameters (parameters.py, declared with descriptors by nodes/params.py), the package
README's parameter table (tools/update_param_tables.py) and the check of the params
files (tests). Defaults are the paper's Table 1 unless the description says otherwise.
No torch here: a node's --help reads these without loading it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Optional

# The paper's three algorithms, then baselines and ablations of the gates for studies
# (docs/results.md): 'respond', the respond gate alone (E(s) < min(E_queue)); 'random',
# requests at random steps (chance random_ask_rate, or random_ask_schedule's count in each
# episode), inside the same budget; 'ask_random', the ask gate and a random draw below
# random_ask_rate (the ask gate thinned by chance instead of by E(s)). Two gates beyond the
# paper, labelled as extensions wherever they appear: 'ask_median', the ask gate and E(s) below
# the median of E_queue; 'joint_rank', the product of D(s)'s and E(s)'s ranks in their queues
# above a threshold tuned online to gate_target_rate; 'novelty' and 'advice_gain', a state's
# distance from those seen and the change of action earlier answers made near it, ranked the same
# way (core/algorithm/state_scores.py).
PAPER_MODES = ('sac', 'qasac', 'eqsac')
EXTENSION_MODES = ('ask_median', 'joint_rank', 'novelty', 'advice_gain')
# The extensions that rank a score of the state itself (state_scores.py) in a queue of its own.
SCORE_MODES = ('novelty', 'advice_gain')


# How tables and figures name and colour each mode (a test holds one entry per mode).
MODE_LABELS = {
    'sac': 'SAC',
    'qasac': 'QASAC',
    'eqsac': 'EQSAC',
    'respond': 'respond gate only',
    'random': 'random requests',
    'ask_random': 'ask gate and chance',
    'ask_median': 'ask gate and E(s) below its median (extension)',
    'joint_rank': 'joint rank of D(s) and E(s) (extension)',
    'novelty': "the state's novelty (extension)",
    'advice_gain': "the advice's gain near the state (extension)",
}
MODE_COLORS = {
    'sac': 'tab:gray',
    'qasac': 'tab:blue',
    'eqsac': 'tab:red',
    'respond': 'tab:purple',
    'random': 'tab:green',
    'ask_random': 'tab:orange',
    'ask_median': 'tab:brown',
    'joint_rank': 'tab:pink',
    'novelty': 'tab:olive',
    'advice_gain': 'tab:cyan',
}


def asks_for_advice(mode: str) -> bool:
    """Every mode but plain SAC asks the expert inside the budget and keeps what it is given in
    D_advising (for the second critic update); SAC never asks and has no D_advising."""
    return mode != 'sac'


MODES = (*PAPER_MODES, 'respond', 'random', 'ask_random', *EXTENSION_MODES)
ADVICE_BATCHES = ('full', 'proportional')
THRESHOLD_KINDS = ('dynamic', 'fixed')
ENTROPY_ESTIMATORS = ('exact', 'monte_carlo')
# How a request reaches the person (core/experts/wheel.py): the paper's one action for one state
# ('answer'), or the wheel for a stretch from the current state ('wheel', beyond the paper);
# 'auto' picks the wheel in a real-time env and the answer in a lock-step one.
ADVICE_PROTOCOLS = ('auto', 'answer', 'wheel')


def advice_protocol(configured: str, realtime: bool) -> str:
    """The protocol a learner uses: ``configured`` (one of ADVICE_PROTOCOLS) for an env that is
    real-time or not ('auto': the wheel in real time, where nothing waits for an answer)."""
    if configured not in ADVICE_PROTOCOLS:
        raise ValueError(f'advice_protocol must be one of {ADVICE_PROTOCOLS}, got {configured!r}')
    if configured == 'auto':
        return 'wheel' if realtime else 'answer'
    return configured


DEVICES = ('cpu', 'cuda')
INT_MAX = 2**31 - 1


def hyper(
    default: Any,
    description: str,
    *,
    range: Optional[tuple] = None,
    choices: Optional[tuple] = None,
    dynamic: bool = False,
    ros_name: Optional[str] = None,
):
    """A LearnerConfig field: ``range`` is inclusive; ``dynamic``: may change while a learner
    runs (a ROS parameter set at run time); ``ros_name``: the parameter's name when it differs."""
    return field(
        default=default,
        metadata={
            'description': description,
            'range': range,
            'choices': choices,
            'dynamic': dynamic,
            'ros_name': ros_name,
        },
    )


@dataclass
class LearnerConfig:
    """Hyperparameters of SAC, QASAC and EQSAC (see each field's description)."""

    mode: str = hyper(
        'eqsac',
        'Learning mode: plain SAC, QASAC (ask gate only) or EQSAC (ask and respond gates); baselines: '
        'respond (respond gate only), random (ask at random steps: random_ask_rate, or random_ask_schedule), '
        'ask_random (the ask gate and a random draw below random_ask_rate); extensions beyond the paper: '
        'ask_median (the ask gate and E(s) below the median of E_queue), joint_rank (the product of the '
        'ranks of D(s) and E(s) in their queues above a threshold tuned to gate_target_rate), novelty (the '
        "state's mean distance to its gate_neighbours nearest of the last gate_memory states seen), "
        'advice_gain (the change of action earlier answers made near the state, distance-weighted over its '
        'gate_neighbours nearest answered states; by chance at gate_target_rate until there are that many): '
        'each ranked in a queue of its own and asked above a threshold tuned to gate_target_rate',
        choices=MODES,
    )
    hidden: tuple[int, ...] = hyper(
        (256, 256),
        'Hidden layer sizes of actor and critics (Table 1: 256x256); refused when the networks cannot fit in memory',
        ros_name='hidden_sizes',
    )
    actor_lr: float = hyper(1e-4, 'Actor learning rate (Table 1)', range=(1e-8, 1.0))
    critic_lr: float = hyper(1e-3, 'Critic learning rate (Table 1)', range=(1e-8, 1.0))
    alpha_lr: float = hyper(1e-4, 'Temperature learning rate (Table 1)', range=(1e-8, 1.0))
    initial_alpha: float = hyper(
        1.0, "Initial entropy temperature alpha (not in the paper; SB3's and CleanRL's start)", range=(1e-6, 100.0)
    )
    gamma: float = hyper(0.99, 'Discount factor (Table 1)', range=(0.0, 1.0))
    tau: float = hyper(0.005, 'Soft target update rate (Table 1)', range=(1e-6, 1.0))
    batch_size: int = hyper(256, 'Minibatch size (not in the paper; SB3 default)', range=(1, 65536))
    replay_capacity: int = hyper(
        500_000,
        'Replay buffer size (Table 1); refused when D and D_advising cannot fit in memory, '
        'naming a capacity that takes half of it',
        range=(1, 50_000_000),
    )
    learning_starts: int = hyper(
        5_000, 'Transitions stored before updates start (Table 1 "minimal buffer size")', range=(1, INT_MAX)
    )
    updates_per_step: int = hyper(1, 'Gradient updates per env step', range=(0, 100))
    random_warmup_steps: int = hyper(
        0, 'Uniform-random actions for the first N steps (off in the paper)', range=(0, INT_MAX)
    )
    seed: int = hyper(42, 'Random seed (Table 1)', range=(0, INT_MAX))
    # Advising (Section 3)
    advising_budget: int = hyper(
        30, 'Early-advising budget: advice only in episodes below it (Eq. 7)', range=(0, INT_MAX), dynamic=True
    )
    advising_budget_s: float = hyper(
        0.0,
        "A budget in the person's seconds: no more requests once the person has spent this long "
        'over the run on requests (from the alert to the answer or the hand-back, reaction included; skips, '
        'windows let pass) and unasked takeovers; 0: none. With advising_budget, '
        'the first one used up ends advice (not in the paper)',
        range=(0.0, 1e9),
        dynamic=True,
    )
    queue_length: int = hyper(15, 'Length of the D and E FIFO queues (Table 1)', range=(1, 100_000))
    threshold_kind: str = hyper('dynamic', 'Dynamic queue thresholds (Eq. 10) or fixed ones', choices=THRESHOLD_KINDS)
    fixed_d_threshold: float = hyper(1.0, 'Ask when D(s) exceeds this (threshold_kind fixed)', range=(0.0, 1e9))
    fixed_e_threshold: float = hyper(0.0, 'Respond when E(s) is below this (threshold_kind fixed)', range=(-1e9, 1e9))
    entropy_estimator: str = hyper(
        'exact',
        'How E(s) (Eq. 9) is computed: exact (the integral by fixed-node quadrature, deterministic) or '
        'monte_carlo (an average over entropy_samples draws, the earlier default)',
        choices=ENTROPY_ESTIMATORS,
    )
    entropy_samples: int = hyper(
        32, 'Monte Carlo samples K of E(s) (Eq. 9) with entropy_estimator monte_carlo', range=(1, 100_000)
    )
    random_ask_rate: float = hyper(
        0.0,
        'Modes random and ask_random: chance of asking at each step inside the budget (random), or at each '
        'step the ask gate opens (ask_random); baselines',
        range=(0.0, 1.0),
    )
    random_ask_schedule: tuple[int, ...] = hyper(
        (),
        'Mode random: requests in each episode (one count per episode from the first), at steps drawn '
        'uniformly among its first random_ask_horizon; a baseline matched in timing. Empty: random_ask_rate',
        range=(0, 100_000),
    )
    random_ask_steps: tuple[int, ...] = hyper(
        (),
        'Mode random, matched step by step (an extension): per episode from the first, its length L and '
        'the steps another run asked at, each episode ended by -1 (L, s1, s2, ..., -1, L, ..., -1). It asks '
        'at (s + o) mod L, o drawn uniformly once per episode: the same count, gaps and runs of requests, '
        'at a random place; requests at steps its own episode ended before are asked in the next episode, '
        "as a block moved by a second offset, so the run's count holds where episodes end elsewhere. "
        'Overrides random_ask_schedule and random_ask_rate. Empty: not used',
        range=(-1, INT_MAX),
    )
    random_ask_horizon: int = hyper(
        200,
        'Mode random with random_ask_schedule: the steps of an episode its requests are spread over',
        range=(1, INT_MAX),
    )
    gate_target_rate: float = hyper(
        0.015,
        'Modes joint_rank, novelty and advice_gain (extensions): the share of budget steps they ask at; '
        'the threshold on the rank moves by gate_threshold_step per step toward this rate (Robbins-Monro). '
        'The default is '
        "EQSAC's rate on Pendulum with Table 1's settings (1.5 % of budget steps, docs/results.md)",
        range=(0.0, 1.0),
    )
    gate_threshold_step: float = hyper(
        0.01,
        'Modes joint_rank, novelty, advice_gain: how far the threshold moves per step toward gate_target_rate',
        range=(1e-6, 1.0),
    )
    gate_neighbours: int = hyper(
        5, 'Modes novelty and advice_gain (extensions): the nearest states a score is taken over', range=(1, 1000)
    )
    gate_score_queue: int = hyper(
        200,
        'Modes novelty and advice_gain: the recent scores a score is ranked among. A queue of n ranks in '
        "steps of 1/n, so it can ask at rates down to about 1/n (200: 0.5 %; Table 1's queue_length of 15 "
        'could not ask below 6 %)',
        range=(2, 100_000),
    )
    gate_memory: int = hyper(
        2048,
        'Modes novelty and advice_gain: the states remembered (the latest seen, and the latest answered)',
        range=(1, 1_000_000),
    )
    request_refractory_steps: int = hyper(
        0,
        'An extension, for any mode that asks: no request within this many steps after the last one of '
        'the same episode (a gate that cannot cluster its requests); 0: off, as in the paper',
        range=(0, INT_MAX),
    )
    takeover_threshold: float = hyper(
        0.0,
        "Mixed initiative: with the deadman held, the person's command replaces the learner's action "
        'once it departs from it by more than this, in [-1, 1] units (any dimension), and for as long as '
        'the deadman stays held; the take-over button (T on the page) does it at once. 0: only the button '
        '(an answer given by steering would otherwise go on as a takeover)',
        range=(0.0, 2.0),
    )
    advice_protocol: str = hyper(
        'auto',
        'How a request reaches the person: answer (the paper: one action for the state asked about), '
        'wheel (beyond the paper: the person is asked to take over from the current state, and drives '
        'until they hand back), or auto: wheel in a real-time env, answer in a lock-step one',
        choices=ADVICE_PROTOCOLS,
    )
    wheel_take_s: float = hyper(
        4.0,
        'Protocol wheel: seconds the person has to take the wheel (press the deadman) after the alert; '
        'the robot drives with its own policy meanwhile, and an untaken request ends as a timeout',
        range=(0.01, 600.0),
        dynamic=True,
    )
    wheel_max_s: float = hyper(
        10.0,
        'Protocol wheel: the longest stretch the person drives once asked; 0: no limit',
        range=(0.0, 3600.0),
        dynamic=True,
    )
    wheel_agree: float = hyper(
        0.1,
        "Protocol wheel: the person's and the policy's actions agree when they are within this, in [-1, 1] "
        'units (every dimension); see wheel_agree_steps',
        range=(0.0, 2.0),
        dynamic=True,
    )
    wheel_agree_steps: int = hyper(
        10,
        'Protocol wheel: hand back to the learner once the actions agree (wheel_agree) this many steps in a '
        'row, as ThriftyDAgger hands back; 0: only on release or wheel_max_s',
        range=(0, INT_MAX),
        dynamic=True,
    )
    takeover_to_advice_memory: bool = hyper(
        True, 'Steps the person took over go to D_advising too, as advice (false: D only)'
    )
    actor_on_advice: bool = hyper(False, 'Also train the actor on the advice batch (an ablation; off in the paper)')
    dual_replay: bool = hyper(
        True, 'Advised transitions also go to D_advising for a second critic update (Section 3.3); false: D only'
    )
    advice_batch: str = hyper(
        'full',
        'Size of the D_advising batch: full (batch_size, the paper) or proportional '
        '(batch_size x |D_advising| / |D|, at least 1; an ablation)',
        choices=ADVICE_BATCHES,
    )
    device: str = hyper(
        'cpu',
        'Torch device of the networks, the acting and the updates (cuda: the current GPU; the replay '
        'memory stays in host memory and each batch is copied over)',
        choices=DEVICES,
    )
    compile_update: bool = hyper(
        False,
        'Compile the whole update into one program (torch.compile) in the background while the first '
        'updates run eagerly; same numbers to float rounding. 1.5-4.7x faster updates, paid back after '
        '4,000-9,000 updates: on in the shipped params files of long runs (pendulum, lunar_lander, '
        'teleop_lunar_lander). Off: the eager update (no compiler start-up; short runs, tests)',
    )

    def __post_init__(self):
        check_fields(self)

    @classmethod
    def from_params(cls, params: dict, node_keys=(), **overrides) -> 'LearnerConfig':
        """From a learner's ROS parameters (a params-file section): config fields under their
        parameter names; ``node_keys`` are the node's own parameters, skipped here. Any other
        key is refused, as the learner node refuses it."""
        names = {ros_name(f): f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(params) - set(names) - set(node_keys))
        if unknown:
            raise ValueError(
                f'unknown learner parameter(s): {", ".join(unknown)}; known: {", ".join(sorted([*names, *node_keys]))}'
            )
        values = {names[k]: v for k, v in params.items() if k in names}
        values.update(overrides)
        return cls(**values)

    def never_asks(self) -> str:
        """Why this configuration can never ask ('' when it can): a random mode with no chance and
        no schedule (`mode:=random` on a shipped params file, whose rate is 0) is SAC, unsaid. Not
        refused: a study's random arm matched to an arm that asked nothing has rate 0 on purpose."""
        if self.mode == 'random' and not (self.random_ask_rate or self.random_ask_schedule or self.random_ask_steps):
            return 'mode random with random_ask_rate 0 and no random_ask_schedule asks nothing: this run is SAC'
        if self.mode == 'ask_random' and not self.random_ask_rate:
            return 'mode ask_random with random_ask_rate 0 asks nothing: this run is SAC'
        return ''

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}  # YAML and JSON know lists


CONFIG_FIELDS = {f.name: f for f in dataclasses.fields(LearnerConfig)}


def ros_name(f: dataclasses.Field) -> str:
    return f.metadata['ros_name'] or f.name


def check_value(name: str, value: Any) -> Any:
    """``value`` for LearnerConfig field ``name`` if it is allowed (ints for floats become floats),
    else ValueError."""
    return check_field(CONFIG_FIELDS[name], value, 'LearnerConfig')


def check_fields(instance) -> None:
    """Check (and normalise) every hyper() field of a dataclass instance, in place."""
    for f in dataclasses.fields(instance):
        setattr(instance, f.name, check_field(f, getattr(instance, f.name), type(instance).__name__))


def check_field(f: dataclasses.Field, value: Any, owner: str) -> Any:
    """``value`` for a field declared with hyper(), or a ValueError naming ``owner.field``."""
    name, meta = f.name, f.metadata
    kind: Any = type(f.default)

    def refuse(expected: str):
        # Named as the ROS parameter too where it differs: a node's user gave `hidden_sizes`.
        ros = f' (ROS parameter {ros_name(f)})' if ros_name(f) != name else ''
        got = 'nothing (an empty list is an unset ROS array)' if value is None else repr(value)
        raise ValueError(f'{owner}.{name}{ros} must be {expected}, got {got}')

    if kind is tuple:
        counts = meta['range'] is not None  # a list of counts in range; else layer sizes
        if value is None and counts:
            return ()  # a ROS integer array left unset
        try:
            if isinstance(value, (str, bytes)) or any(isinstance(h, bool) or h != int(h) for h in value):
                raise ValueError
            value = tuple(int(h) for h in value)
        except (TypeError, ValueError, OverflowError):
            refuse('a list of integers' if counts else 'a list of layer sizes')
        if counts:
            low, high = meta['range']
            if any(not low <= h <= high for h in value):
                refuse(f'a list of integers in [{low}, {high}]')
            return value
        if not value or any(h < 1 for h in value):
            refuse('positive layer sizes')
        return value
    if kind is bool:
        if not isinstance(value, bool):
            refuse('true or false')
        return value
    if kind is str:
        if value not in meta['choices']:
            refuse(f'one of {meta["choices"]}')
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and not isinstance(value, int)):
        refuse('an integer' if kind is int else 'a number')
    value = kind(value)
    low, high = meta['range']
    if not low <= value <= high:
        refuse(f'in [{low:g}, {high:g}]')
    return value
