"""expert: serves the Advise service with a built-in controller or an exported policy."""

from __future__ import annotations

import time

from rclpy.node import Node

from eqhrl_interfaces.srv import Advise

from ..core.experts import Advice, make_expert
from .advise_msgs import answer, fill_response
from .params import EXPERT_PARAMS, choices_validator, declare, reject_unknown_overrides
from .spinning import run_node


class ExpertNode(Node):
    def __init__(self, backend=None, **kwargs):
        """``backend`` (a core Expert callable) replaces the one the parameters choose."""
        super().__init__('expert', **kwargs)
        reject_unknown_overrides(self, EXPERT_PARAMS)
        self.params = declare(self, EXPERT_PARAMS)
        self.add_on_set_parameters_callback(choices_validator(EXPERT_PARAMS))
        p = self.params
        self.backend = backend or make_expert(p['backend'], p['env_id'], p['policy_path'])
        self.requests = 0
        self.create_service(Advise, 'advise', self._on_request)
        self.get_logger().info(f"serving 'advise' with {getattr(self.backend, 'name', type(self.backend).__name__)}")

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
