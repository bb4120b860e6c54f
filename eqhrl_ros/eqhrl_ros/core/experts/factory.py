"""The expert a backend name stands for (the expert node's `backend` parameter, the experiment
runner's --expert): above the experts it builds, so that none of them imports it."""

from __future__ import annotations

from .controllers import heuristic_expert
from .simulated_human import SimulatedHuman

EXPERT_BACKENDS = ('heuristic', 'policy', 'simulated_human')


def make_expert(backend: str, env_id: str, policy_path: str = '', human_limits=None, seed: int = 0, takeover=None):
    """The expert a backend name stands for: the env's built-in controller, a policy file
    exported by a learner (policy.PolicyExpert), or a simulated person who imitates the
    policy (when policy_path is set) or else the controller, with ``human_limits``
    (simulated_human.HumanLimits) and, in-process, ``takeover`` (a TakeoverRule: they also
    take over unasked). ValueError names what is missing."""
    if backend == 'simulated_human':
        model = make_expert('policy' if policy_path else 'heuristic', env_id, policy_path)
        return SimulatedHuman(model, human_limits, seed, takeover=takeover)
    if takeover is not None:
        raise ValueError(f'only a simulated person takes over (backend simulated_human), not {backend!r}')
    if backend == 'policy':
        if not policy_path:
            raise ValueError("backend 'policy' needs a policy file (policy_path is empty)")
        from .policy import PolicyExpert

        return PolicyExpert(policy_path, name=f'policy:{policy_path}')
    if backend == 'heuristic':
        return heuristic_expert(env_id)
    raise ValueError(f'expert backend {backend!r} is not one of {EXPERT_BACKENDS}')
