"""expert: serves the Advise service with a built-in controller or an exported policy."""

from __future__ import annotations

import time

from rclpy.node import Node

from eqhrl_interfaces.srv import Advise

from ..core.checkpoint import PolicyExpert
from ..core.experts import Advice, heuristic_expert
from .advise_msgs import answer, fill_response
from .lifecycle import run_node
from .params import EXPERT_PARAMS, choices_validator, declare, reject_unknown_overrides


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
            return PolicyExpert(p['policy_path'], name=f'policy:{p["policy_path"]}')
        return heuristic_expert(p['env_id'])

    def _on_request(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        self.requests += 1
        name = self.get_fully_qualified_name()
        delay = self.get_parameter('response_delay_s').value
        if delay > 0:
            time.sleep(delay)
        if not self.get_parameter('enabled').value:
            return fill_response(response, Advice.decline('expert disabled (parameter enabled is false)'), name)
        return answer(self.backend, request, response, name, self.get_logger())


def main(args=None):
    run_node(ExpertNode, args, name='expert')


if __name__ == '__main__':
    main()
