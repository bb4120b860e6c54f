"""ROS plumbing: the built Advise service and Float32MultiArray topics, in a private domain."""

import contextlib
import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.srv import Advise


def spin_until(executor, condition, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return condition()


def test_advise_service_round_trip(ros_context):
    server = rclpy.create_node('advise_server', context=ros_context)
    client_node = rclpy.create_node('advise_client', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    try:

        def serve(request, response):
            response.advised = request.discrepancy > 1.0
            response.action = [2.0 * x for x in request.proposed_action]
            response.reason = '' if response.advised else 'critics agree'
            response.expert_name = 'doubler'
            return response

        server.create_service(Advise, 'advise', serve)
        client = client_node.create_client(Advise, 'advise')
        executor.add_node(server)
        executor.add_node(client_node)
        assert spin_until(executor, client.service_is_ready)

        request = Advise.Request(
            observation=[0.1, 0.2, 0.3],
            proposed_action=[0.25, -0.5],
            action_low=[-1.0, -1.0],
            action_high=[1.0, 1.0],
            discrepancy=1.5,
            entropy=-0.3,
            episode=4,
            step=17,
        )
        future = client.call_async(request)
        executor.spin_until_future_complete(future, timeout_sec=5.0)
        response = future.result()
        assert response.advised and list(response.action) == [0.5, -1.0]
        assert response.expert_name == 'doubler'

        request.discrepancy = 0.5
        future = client.call_async(request)
        executor.spin_until_future_complete(future, timeout_sec=5.0)
        assert not future.result().advised and future.result().reason == 'critics agree'
    finally:
        executor.shutdown()
        server.destroy_node()
        client_node.destroy_node()


@contextlib.contextmanager
def loopback(ros_context, topic: str):
    """A node subscribed to its own publisher on ``topic``: (publisher, received, executor)."""
    node = rclpy.create_node('loopback', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    received = []
    try:
        node.create_subscription(Float32MultiArray, topic, received.append, 10)
        publisher = node.create_publisher(Float32MultiArray, topic, 10)
        executor.add_node(node)
        assert spin_until(executor, lambda: publisher.get_subscription_count() > 0)
        yield publisher, received, executor
    finally:
        executor.shutdown()
        node.destroy_node()


def test_float32_multiarray_publish_subscribe(ros_context):
    with loopback(ros_context, 'numbers') as (publisher, received, executor):
        publisher.publish(Float32MultiArray(data=[1.0, -2.5, 3.25]))
        assert spin_until(executor, lambda: len(received) == 1)
        assert list(received[0].data) == pytest.approx([1.0, -2.5, 3.25])


def test_tests_run_in_a_private_domain():
    import os

    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 1 <= int(os.environ['ROS_DOMAIN_ID']) <= 100


def test_serialized_outgoing_messages_arrive_as_labelled_messages(ros_context):
    # The env and learner publish per-step messages as bytes written in place
    # (messages.OutgoingMessage). A plain subscriber must receive the labelled message,
    # and three refills published back to back must arrive as three different steps.
    from eqhrl_ros.nodes import messages

    with loopback(ros_context, 'observation') as (publisher, received, executor):
        out = messages.observation_out(3)
        assert out.serialized
        for step in range(3):
            data = out.fill([0.1 * step, 0.2, 0.3], -float(step), step == 2, False, 4, step)
            assert isinstance(data, bytes)
            publisher.publish(data)
        assert spin_until(executor, lambda: len(received) == 3)
        steps = [messages.parse_observation(m, 3) for m in received]
        assert [s.step for s in steps] == [0, 1, 2]
        assert [s.reward for s in steps] == [0.0, -1.0, -2.0]
        assert [s.terminated for s in steps] == [False, False, True]
        assert [s.obs[0] for s in steps] == pytest.approx([0.0, 0.1, 0.2])
        assert received[2].layout == messages.observation_msg([0.0] * 3, 0.0, False, False, 0, 0).layout
        assert messages.parse_fields(received[2])['episode'] == 4.0
        with pytest.raises(messages.MessageError, match='2 \\+ 5 values for a message of 3 \\+ 5'):
            out.fill([0.1, 0.2], 0.0, False, False, 4, 3)


def test_a_raw_subscription_reads_any_publishers_layout(ros_context):
    # The learner and env subscribe raw (messages.SerializedReader): the fast path for
    # the layout it has seen, full deserialization for anything else.
    from eqhrl_ros.nodes import messages

    node = rclpy.create_node('raw_loopback', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    received = []
    try:
        node.create_subscription(Float32MultiArray, 'action', received.append, 10, raw=True)
        publisher = node.create_publisher(Float32MultiArray, 'action', 10)
        executor.add_node(node)
        assert spin_until(executor, lambda: publisher.get_subscription_count() > 0)
        out = messages.action_out(2)
        publisher.publish(out.fill([0.5, -0.5], 1, 7))
        publisher.publish(out.fill([0.25, 1.0], 1, 8))
        publisher.publish(Float32MultiArray(data=[0.75, -1.0]))  # bare, unlabelled
        publisher.publish(messages.action_msg([0.1, 0.2], 2, 0))  # built elsewhere
        publisher.publish(out.fill([float('nan'), 0.0], 2, 1))
        assert spin_until(executor, lambda: len(received) == 5)
        assert all(isinstance(data, bytes) for data in received)
        reader = messages.SerializedReader()
        parsed = [messages.parse_action(reader.values(data), 2) for data in received[:4]]
        assert [(a.tolist(), tag) for a, tag in parsed] == [
            ([0.5, -0.5], (1, 7)),
            ([0.25, 1.0], (1, 8)),
            ([0.75, -1.0], None),
            (pytest.approx([0.1, 0.2]), (2, 0)),
        ]
        with pytest.raises(messages.MessageError, match='non-finite'):
            messages.parse_action(reader.values(received[4]), 2)
    finally:
        executor.shutdown()
        node.destroy_node()


def test_a_node_stopped_between_two_ready_callbacks_is_destroyed_at_once(ros_context):
    """destroy_node() right after spin() returns on a stop read between two ready callbacks.
    (CI once saw an expert node wait forever in destroy_node() after SIGTERM, for handles of
    ready waitables that rclpy's executor still held; spin() now shuts its executor down. This
    test covers the timers' path, which never held handles; the waitables' case was not
    reproduced here.)"""
    import threading

    from eqhrl_ros.nodes.spinning import spin

    class Stop:
        requested = False

    stop = Stop()
    node = rclpy.create_node('two_timers', context=ros_context)
    calls = []

    def tick(which):
        calls.append(which)
        stop.requested = True

    time.sleep(0.01)
    node.create_timer(0.001, lambda: tick('a'))
    node.create_timer(0.001, lambda: tick('b'))
    time.sleep(0.01)  # both timers are due before the first wait
    spin(node, stop)
    assert calls  # it spun until the stop was read
    destroyed = threading.Event()
    threading.Thread(target=lambda: (node.destroy_node(), destroyed.set()), daemon=True).start()
    assert destroyed.wait(5.0), 'destroy_node() is still waiting for handles the executor holds'
