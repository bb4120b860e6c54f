"""expert: serves the Advise service with a built-in controller or an exported policy."""

from __future__ import annotations

import time

import numpy as np
from rclpy.node import Node

from eqhrl_interfaces.srv import Advise

from ..core.checkpoint import PolicyExpert
from ..core.experts import AdviceRequest, heuristic_expert
from .lifecycle import run_node
from .params import EXPERT_PARAMS, choices_validator, declare, reject_unknown_overrides


def request_from_msg(msg: Advise.Request) -> AdviceRequest:
    def arr(values):
        return np.asarray(values, dtype=np.float32)
    return AdviceRequest(arr(msg.observation), arr(msg.proposed_action), arr(msg.action_low),
                         arr(msg.action_high), float(msg.discrepancy), float(msg.entropy),
                         int(msg.episode), int(msg.step))


class ExpertNode(Node):
    def __init__(self, backend=None, **kwargs):
        """``backend`` (a core Expert callable) replaces the one the parameters choose."""
        super().__init__('expert', **kwargs)
        reject_unknown_overrides(self, EXPERT_PARAMS)
        self.params = declare(self, EXPERT_PARAMS)
        self.add_on_set_parameters_callback(choices_validator(EXPERT_PARAMS))
        self.backend = backend or self._make_backend()
        self.requests = 0
        self.create_service(Advise, 'advise', self._on_request)
        self.get_logger().info(f"serving 'advise' with {getattr(self.backend, 'name', type(self.backend).__name__)}")

    def _make_backend(self):
        p = self.params
        if p['backend'] == 'policy':
            if not p['policy_path']:
                raise ValueError("parameter 'policy_path' is empty; backend 'policy' needs a policy file")
            return PolicyExpert(p['policy_path'], name=f"policy:{p['policy_path']}")
        return heuristic_expert(p['env_id'])

    def _on_request(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        self.requests += 1
        response.expert_name = self.get_fully_qualified_name()
        delay = self.get_parameter('response_delay_s').value
        if delay > 0:
            time.sleep(delay)
        if not self.get_parameter('enabled').value:
            response.advised, response.reason = False, 'expert disabled (parameter enabled is false)'
            return response
        try:
            advice = self.backend(request_from_msg(request))
        except Exception as error:   # a backend bug declines one request; the service lives on
            self.get_logger().error(f'backend failed: {error!r}')
            response.advised, response.reason = False, f'expert error: {error}'
            return response
        response.advised = advice.advised
        if advice.advised:
            response.action = np.asarray(advice.action, dtype=np.float32).tolist()
        else:
            response.reason = advice.reason or 'declined'
        return response


def main(args=None):
    run_node(ExpertNode, args, name='expert')

if __name__ == '__main__':
    main()
