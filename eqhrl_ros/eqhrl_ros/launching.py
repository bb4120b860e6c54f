"""What the package's launch files share: a node that exits with an error ends the launch with one.

`ros2 launch` exits 0 when a node it started exits with an error (a trainer that refuses a bad
parameter, a learner whose checkpoint is corrupt), so a script or a service manager would take
a run that never began for one that ended well. An exception raised by an event handler makes
the launch shut everything down and exit non-zero, with the reason in its log.
"""

from __future__ import annotations


def refusal_reason(process_name: str, returncode) -> str:
    """Why the launch stops, or '' when ``returncode`` is a normal end (0) or a signal (negative:
    the launch's own SIGINT or SIGTERM at shutdown)."""
    if returncode is None or returncode <= 0:
        return ''
    return f'{process_name} exited with code {returncode} (its log above says why): stopping the launch'


def fail_launch_on_error(node):
    """An action to add beside ``node`` in a launch description: when the node's process exits
    with an error, the launch stops and `ros2 launch` exits non-zero."""
    from launch.actions import RegisterEventHandler
    from launch.event_handlers import OnProcessExit

    def on_exit(event, context):
        reason = refusal_reason(getattr(event, 'process_name', '?'), event.returncode)
        if reason:
            raise RuntimeError(reason)

    return RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit))
