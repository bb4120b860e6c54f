"""torch's threads fitted to the machine (core/algorithm/cpu_threads.py): one thread while another
process holds the cores, every thread once they are free, standing down for a caller's setting."""

import numpy as np
import pytest
import torch

from eqhrl_ros.core.algorithm import cpu_threads
from eqhrl_ros.core.algorithm.cpu_threads import (
    CROWDED,
    FREE_CORES,
    MAX_BACKOFF,
    REPORT_EVERY_S,
    WINDOW_S,
    ThreadGovernor,
)


class Machine:
    """A clock, the updates' thread's wait for a CPU and the machine's idle cores, advanced by hand;
    torch's thread count as the governor sets it."""

    def __init__(self, threads: int = 2):
        self.now = self.waited = self.idle = 0.0
        self.threads = threads

    def window(self, waiting: float = 0.0, idle_cores: float = 0.0) -> None:
        """One window passes: the thread waited ``waiting`` of it, ``idle_cores`` were idle."""
        self.now += WINDOW_S
        self.waited += waiting * WINDOW_S
        self.idle += idle_cores * WINDOW_S

    def governor(self, report=None) -> ThreadGovernor:
        return ThreadGovernor(
            self.threads,
            clock=lambda: self.now,
            waited=lambda: self.waited,
            idle=lambda: self.idle,
            get_threads=lambda: self.threads,
            set_threads=self.set,
            report=report,
        )

    def set(self, threads: int) -> None:
        self.threads = threads


CROWD, QUIET = CROWDED + 0.2, 0.0  # the updates' thread's share of a window spent waiting for a CPU
FREE, TAKEN = FREE_CORES + 0.2, 0.0  # idle cores over a window


def test_a_quiet_machine_keeps_every_thread():
    machine = Machine(2)
    governor = machine.governor()
    for _ in range(20):
        machine.window(QUIET, TAKEN)  # our own spinning threads leave no core idle
        governor.tick()
    assert machine.threads == 2 and governor.switches == 0


def test_a_crowded_machine_gets_one_thread_and_every_thread_back_once_cores_are_free():
    machine = Machine(2)
    governor = machine.governor()
    machine.window(CROWD, TAKEN)
    governor.tick()
    assert machine.threads == 1
    for _ in range(5):  # one thread, the other process on the other core: nothing idle
        machine.window(QUIET, TAKEN)
        governor.tick()
    assert machine.threads == 1
    machine.window(QUIET, FREE)  # the other process ended
    governor.tick()
    assert machine.threads == 2 and governor.switches == 2


def test_each_switch_is_told_in_one_line_with_its_reason_and_a_flipping_machine_in_a_count():
    """A learner in lock-step with an env on 2 cores flipped 15 times a minute, each an info line
    (2026-12-05). Now at most one line every REPORT_EVERY_S, the last one saying the count it has."""
    lines: list = []
    machine = Machine(2)
    governor = machine.governor(report=lines.append)
    machine.window(0.35, TAKEN)
    governor.tick()
    assert lines == ['torch threads 1 (of 2): the updates waited for a CPU 35% of the last 0.5 s']
    machine.window(QUIET, 0.9)
    governor.tick()  # back to every thread one window later: counted, not yet told
    machine.window(CROWD, TAKEN)
    governor.tick()
    assert machine.threads == 1 and governor.switches == 3 and len(lines) == 1
    while machine.now < REPORT_EVERY_S + WINDOW_S:  # one thread, nothing idle: no switch, and then a line
        machine.window(QUIET, TAKEN)
        governor.tick()
    assert lines[1:] == [
        f'torch threads 1 (of 2), after 2 switches in the last {REPORT_EVERY_S:.0f} s '
        '(the last: the updates waited for a CPU 35% of the last 0.5 s)'
    ]
    told_at = machine.now
    while machine.now < told_at + REPORT_EVERY_S:
        machine.window(QUIET, TAKEN)
        governor.tick()
    machine.window(QUIET, 0.9)  # a switch long after the last line is told at once
    governor.tick()
    assert machine.threads == 2 and lines[2:] == [
        'torch threads 2 (of 2): the machine left 0.9 cores idle over the last 0.5 s'
    ]


def test_nothing_changes_before_a_window_is_over():
    machine = Machine(2)
    governor = machine.governor()
    machine.window(CROWD, TAKEN)
    machine.now -= WINDOW_S / 2  # half a window: the waiting is there, the window is not over
    governor.tick()
    assert machine.threads == 2
    machine.now += WINDOW_S / 2
    governor.tick()
    assert machine.threads == 1


def test_a_return_that_finds_the_cores_taken_again_waits_longer_before_the_next():
    """A container whose /proc/stat sees a bigger host: the idle cores are another's, and each
    return to every thread meets the crowd again. The waits double, up to MAX_BACKOFF windows."""
    machine = Machine(2)
    governor = machine.governor()
    machine.window(CROWD, TAKEN)
    governor.tick()
    waits = []
    for _ in range(9):
        windows = 0
        while machine.threads == 1:
            machine.window(QUIET, FREE)  # looks free ...
            governor.tick()
            windows += 1
        waits.append(windows)
        machine.window(CROWD, TAKEN)  # ... and is not
        governor.tick()
        assert machine.threads == 1
    assert waits[:7] == [1, 2, 4, 8, 16, 32, 64] and waits[7:] == [MAX_BACKOFF, MAX_BACKOFF]


def test_a_return_shorter_than_the_wait_before_it_still_grows_the_wait():
    """A learner in lock-step with an env beside it: each return to every thread lasted a few
    windows, the waits started over at one window, and the count flipped every few seconds."""
    machine = Machine(2)
    governor = machine.governor()
    waits = []
    for stay in (1, 1, 1, 5, 5):  # windows at every thread before the crowd comes back
        machine.window(CROWD, TAKEN)
        governor.tick()
        windows = 0
        while machine.threads == 1:
            machine.window(QUIET, FREE)
            governor.tick()
            windows += 1
        waits.append(windows)
        for _ in range(stay - 1):
            machine.window(QUIET, TAKEN)
            governor.tick()
    assert waits == [1, 2, 4, 8, 16]


def test_a_crowd_long_after_a_return_starts_the_waits_over():
    machine = Machine(2)
    governor = machine.governor()
    for _ in range(3):  # three quick returns: the wait grows to 4 windows
        machine.window(CROWD, TAKEN)
        governor.tick()
        while machine.threads == 1:
            machine.window(QUIET, FREE)
            governor.tick()
    for _ in range(10):  # every thread for a while, then a crowd again
        machine.window(QUIET, TAKEN)
        governor.tick()
    machine.window(CROWD, TAKEN)
    governor.tick()
    machine.window(QUIET, FREE)
    governor.tick()
    assert machine.threads == 2  # back after one window


def test_a_callers_own_thread_count_is_kept():
    machine = Machine(2)
    governor = machine.governor()
    machine.threads = 4  # a script's torch.set_num_threads(4) between updates
    machine.window(CROWD, TAKEN)
    governor.tick()
    assert machine.threads == 4 and 'by its caller' in governor.standing_down
    machine.threads = 2
    machine.window(CROWD, TAKEN)
    governor.tick()
    assert machine.threads == 2  # stood down for good


def test_one_thread_to_begin_with_is_left_alone():
    machine = Machine(1)
    governor = machine.governor()
    machine.window(QUIET, FREE)
    governor.tick()
    assert machine.threads == 1 and governor.standing_down == 'torch has one thread'


def test_without_proc_it_stands_down():
    def missing() -> float:
        raise FileNotFoundError('/proc/thread-self/schedstat')

    machine = Machine(2)
    governor = ThreadGovernor(2, clock=lambda: machine.now, waited=missing, idle=lambda: 0.0)
    machine.window(CROWD, TAKEN)
    governor.tick()
    assert governor.standing_down == 'no /proc to read' and governor.threads == 2


def test_the_readers_read_this_machine():
    first = (cpu_threads.thread_waited_s(), cpu_threads.idle_core_s())
    torch.ones(1000).sum()
    second = (cpu_threads.thread_waited_s(), cpu_threads.idle_core_s())
    assert all(0.0 <= a <= b for a, b in zip(first, second))


@pytest.fixture
def process_state(monkeypatch):
    """The module's process-wide state and torch's thread count, restored after the test."""
    threads = torch.get_num_threads()
    monkeypatch.setattr(cpu_threads, '_governor', None)
    monkeypatch.setattr(cpu_threads, '_fixed', False)
    monkeypatch.setattr(cpu_threads, '_report', None)
    yield
    torch.set_num_threads(threads)


def test_a_learners_updates_run_the_processs_governor_unless_the_count_is_fixed(process_state):
    from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig

    learner = EQSACLearner(
        3, np.array([-2.0], np.float32), np.array([2.0], np.float32), LearnerConfig(hidden=(16, 16), batch_size=8)
    )
    rng = np.random.default_rng(0)
    for _ in range(20):
        learner.replay.add(rng.normal(size=3), [0.1], -1.0, rng.normal(size=3), False)
    torch.set_num_threads(2)
    learner.update()
    assert cpu_threads.governor() is not None and cpu_threads.governor().most == 2
    lines: list = []
    cpu_threads.for_node(0, lines.append)  # a node's torch_threads: 0, its logger told of switches
    assert cpu_threads.governor().report == lines.append
    cpu_threads.for_node(1, lines.append)  # a node's torch_threads: 1
    learner.update()
    assert cpu_threads.governor() is None and torch.get_num_threads() == 1


def test_a_compile_while_the_governor_has_one_thread_builds_its_kernels_for_every_thread(process_state, monkeypatch):
    """A compiled program's fused kernels keep the team size they were built for, so a compile
    that ran while the machine was crowded (one thread) left them serial for good; they are now
    built for the governor's full count (compiled_update.py passes cpu_threads.most())."""
    from eqhrl_ros.core.algorithm import compiled_update

    machine = Machine(threads=2)
    governor = machine.governor()
    monkeypatch.setattr(cpu_threads, '_governor', governor)
    machine.window(waiting=CROWD)
    governor.tick()
    assert machine.threads == 1
    torch.set_num_threads(1)  # what the real governor's setter would have done
    assert cpu_threads.most() == 2  # crowded now: the most is still 2
    options = []
    monkeypatch.setattr(compiled_update.torch, 'compile', lambda function, **kw: options.append(kw['options']))
    monkeypatch.setattr(compiled_update.threading, 'Thread', lambda **kw: type('T', (), {'start': lambda self: None})())
    learner_updater = _small_learner().updater
    learner_updater.make_optimizers()
    compiled_update.CompiledUpdate(learner_updater)
    assert options[0]['cpp.threads'] == 2
    cpu_threads.fix(1)  # a node's torch_threads: 1: the count is the caller's
    assert cpu_threads.most() == torch.get_num_threads() == 1


def _small_learner():
    from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig

    return EQSACLearner(
        3, np.array([-2.0], np.float32), np.array([2.0], np.float32), LearnerConfig(hidden=(16, 16), batch_size=8)
    )


def test_an_update_computes_the_same_weights_whatever_the_thread_count(process_state):
    """Switching between 1 and 2 threads changes the numbers by float rounding at most (to the
    bit on the project's machine), so a fitted run learns what a fixed one would."""
    from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig

    weights = []
    for pattern in ([2] * 8, [2, 1] * 4):
        learner = EQSACLearner(
            3,
            np.array([-2.0], np.float32),
            np.array([2.0], np.float32),
            LearnerConfig(mode='eqsac', hidden=(256, 256), batch_size=256, seed=3),
        )
        rng = np.random.default_rng(0)
        for i in range(300):
            learner.replay.add(rng.normal(size=3), [0.1], -1.0, rng.normal(size=3), False)
            if i % 10 == 0:
                learner.advice_replay.add(rng.normal(size=3), [0.2], -1.0, rng.normal(size=3), False)
        for threads in pattern:
            cpu_threads.fix(threads)
            learner.update()
        networks = (learner.policy.actor, learner.critics.critic)
        weights.append(torch.cat([p.detach().flatten() for net in networks for p in net.parameters()]))
    assert torch.allclose(weights[0], weights[1], rtol=1e-5, atol=1e-6)
