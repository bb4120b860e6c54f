"""The EQ-HRL learning core. Imports no ROS module: nodes, scripts and tests all drive it.

- equations.py   every equation of the paper (Eqs. 4-10), named as the paper names it
- networks.py    the squashed-Gaussian actor and the twin critics
- replay.py      replay memories D and D_advising
- advising.py    FIFO queues, dynamic/fixed thresholds and the early-advising budget
- learner.py     EQSACLearner: SAC, QASAC and EQSAC (Algorithm 1)
- experts.py     the expert interface and built-in controllers
- checkpoint.py  safe checkpoints and exported policies
- envs.py        env construction, action scaling, success per env
- training.py    the in-process training loop
"""

from .advising import AdvisingGates, FifoQueue, GateDecision
from .checkpoint import CheckpointError, PolicyExpert, export_policy, load_checkpoint, save_checkpoint
from .envs import ActionScaler, make_env, success_criterion
from .experts import Advice, AdviceRequest, heuristic_expert
from .learner import EpisodeSummary, EQSACLearner, LearnerConfig, Proposal
from .training import run_episode, train

__all__ = [
    'ActionScaler', 'Advice', 'AdviceRequest', 'AdvisingGates', 'CheckpointError', 'EQSACLearner',
    'EpisodeSummary', 'FifoQueue', 'GateDecision', 'LearnerConfig', 'PolicyExpert', 'Proposal',
    'export_policy', 'heuristic_expert', 'load_checkpoint', 'make_env', 'run_episode',
    'save_checkpoint', 'success_criterion', 'train',
]
