"""ROS 2 nodes: thin adapters between topics/services and eqhrl_ros.core.

Each node is a ``*_node.py``; what a node does besides its wiring sits beside it:
- acting_node.py (the learner's and the actors' shared half): advice_client.py (its requests),
  acting_health.py (its /diagnostics), episode_tracking.py (what each observation means for the
  episode: gaps, restarts, stalls, stops), person_wheel.py (who drives each step: the learner,
  the person asked to take the wheel, or unasked; the rules are core/experts/wheel.py and
  takeover.py);
- learner_node.py, actor_node.py, trainer_node.py (trainer_health.py, trainer_msgs.py);
- advice_console_node.py (the ROS side) and console_server.py (the page's web server and its
  guards, with connection_guard.py);
- gym_env_node.py, double_integrator_env_node.py, expert_node.py, teleop_expert_node.py,
  keyboard_teleop_node.py, policy_driver_node.py (a trained policy drives the env).
Shared: messages.py and advise_msgs.py (message layouts), params.py (declaring parameters),
env_info.py, graph_trust.py, health.py, recording.py, run_files.py, spinning.py, launching.py
(what the launch files share).
"""
