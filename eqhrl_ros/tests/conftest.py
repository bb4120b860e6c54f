"""Test isolation: every test run talks ROS only to itself.

Set before rclpy is imported anywhere: a private ROS domain derived from the
process id, and localhost-only discovery, so that two runs on one machine (or a
run beside a real robot) never hear each other. Child processes inherit both.
"""

import os

os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)  # 1..100, valid on every platform
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '0')
os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')  # pygame renders rgb_array frames without a display

import pytest  # noqa: E402
import torch  # noqa: E402

# Two cores: keep torch from oversubscribing when tests start ROS node threads.
torch.set_num_threads(1)


@pytest.fixture
def ros_context():
    """A private rclpy context, shut down after the test whatever happens."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.fixture
def harness(ros_context, request):
    """Nodes spun by one executor in the test thread; all destroyed after the test.

    The executor is rclpy's SingleThreadedExecutor unless a test parametrizes
    ``harness`` indirectly with another kind ('events', 'multi')."""
    from ros_helpers import Harness

    h = Harness(ros_context, getattr(request, 'param', 'single'))
    try:
        yield h
    finally:
        h.close()
