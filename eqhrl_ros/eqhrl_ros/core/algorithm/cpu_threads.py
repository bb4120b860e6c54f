"""torch's CPU threads fitted to the machine as the learner runs: every thread torch was given while
the cores are free, one thread while another process is busy beside the learner.

Why (docs/performance.md, "A busy machine" and "Fitting torch's threads to the machine"): torch's
OpenMP threads spin a while between parallel regions before they sleep. On a quiet machine that
is what makes 2 threads fast: a worker that slept costs the next region 65-100 us to wake on a
VM, and a compiled SAC step has a dozen and more such regions. Beside a CPU-bound process the
spinning threads fight it for the cores, and the learner kept 24-31 % of its quiet speed at
2 threads, where at 1 thread it kept 89-102 %. No spin count buys both.

So the updates' own thread looks, every WINDOW_S (updater.py calls ``adapt`` after each
update; OpenMP's thread count belongs to the thread that sets it):

- with every thread: if that thread waited for a CPU (runnable, not running: /proc's schedstat)
  more than CROWDED of the window, another process holds the cores: it drops to one thread;
- with one thread: once the machine left FREE_CORES idle over a window (/proc/stat), it
  goes back to every thread. A return that finds the cores taken again before it has lasted as
  long as the wait before it (and at least two windows) doubles the wait before the next (up to
  MAX_BACKOFF windows), so that a container whose /proc/stat sees a bigger host, or a learner in
  lock-step with an env beside it, does not flip every second.

Each switch is told in one line, at most one line every REPORT_EVERY_S: switches in between are
counted and told together in the next line, so the last line always says the count torch has.

It stands down for good where someone else sets torch's thread count (``fix``, for a node's
torch_threads > 0, via ``for_node``; a script's torch.set_num_threads between updates), where torch has one thread
to begin with, and where /proc cannot be read (not Linux). The numbers do not depend on it: an
update computes the same weights at 1 and 2 threads (to the bit on the project's machine, eager
and compiled; tests/core/algorithm/test_cpu_threads.py checks it to float rounding).
"""

from __future__ import annotations

import os
import time
from typing import Callable, Optional

import torch

WINDOW_S = 0.5  # how often the updates' thread looks
CROWDED = 0.15  # with every thread: waited for a CPU over this share of the window -> one thread
FREE_CORES = 0.7  # with one thread: the machine left this many cores idle over the window -> every thread
MAX_BACKOFF = 64  # windows: the longest wait before trying every thread again
REPORT_EVERY_S = 30.0  # at most one line per this: a machine that flips gets a count, not a line a second


def thread_waited_s() -> float:
    """Seconds the calling thread has spent runnable but not running (its schedstat's second field)."""
    with open('/proc/thread-self/schedstat') as f:
        return int(f.read().split()[1]) / 1e9


def idle_core_s() -> float:
    """Seconds of idle (and I/O wait) summed over the machine's CPUs since boot, from /proc/stat."""
    with open('/proc/stat') as f:
        fields = f.readline().split()
    return (int(fields[4]) + int(fields[5])) / os.sysconf('SC_CLK_TCK')


class ThreadGovernor:
    """One process's torch thread count: ``most`` while the cores are free, 1 while crowded. The
    readers, the clock and torch's setters are arguments so that tests can drive it."""

    def __init__(
        self,
        most: int,
        clock: Callable[[], float] = time.monotonic,
        waited: Callable[[], float] = thread_waited_s,
        idle: Callable[[], float] = idle_core_s,
        get_threads: Callable[[], int] = torch.get_num_threads,
        set_threads: Callable[[int], None] = torch.set_num_threads,
        report: Callable[[str], None] | None = None,
    ):
        self.most, self.threads = most, most
        self._clock, self._waited, self._idle = clock, waited, idle
        self._get, self._set = get_threads, set_threads
        self.report = report  # told of each switch, in one line (a node's logger)
        self.standing_down = '' if most > 1 else 'torch has one thread'
        self.switches = 0
        self._untold, self._last_why = 0, ''  # switches not yet told (REPORT_EVERY_S), the last one's reason
        self._told_at: Optional[float] = None
        self._backoff = 1  # windows to wait at one thread before trying every thread again
        self._windows_here = 0  # windows since the last switch
        self._since: Optional[tuple] = None
        if not self.standing_down:
            self._since = self._read()

    def _read(self) -> Optional[tuple]:
        try:
            return self._clock(), self._waited(), self._idle()
        except (OSError, ValueError, IndexError):  # no /proc (not Linux), or one we cannot parse
            self.standing_down = 'no /proc to read'
            return None

    def tick(self) -> None:
        """After an update, in the updates' thread: look once the window is over, and switch."""
        if self.standing_down or self._since is None:
            return
        if self._get() != self.threads:  # someone else set torch's threads: theirs to keep
            self.standing_down = f'torch set to {self._get()} threads by its caller'
            return
        start, waited_before, idle_before = self._since
        clock = self._clock()
        self._tell(clock)
        if clock - start < WINDOW_S:
            return
        now = self._read()
        if now is None:
            return
        seconds = now[0] - start
        waited, idle = (now[1] - waited_before) / seconds, (now[2] - idle_before) / seconds
        self._since = now
        self._windows_here += 1
        if self.threads > 1 and waited > CROWDED:
            # Found crowded before the return outlasted the wait before it: wait longer next time.
            quick = self.switches and self._windows_here <= max(2, self._backoff)
            self._backoff = min(2 * self._backoff, MAX_BACKOFF) if quick else 1
            self._switch(1, f'the updates waited for a CPU {waited:.0%} of the last {seconds:.1f} s')
        elif self.threads == 1 and idle >= FREE_CORES and self._windows_here >= self._backoff:
            self._switch(self.most, f'the machine left {idle:.1f} cores idle over the last {seconds:.1f} s')

    def _switch(self, threads: int, why: str) -> None:
        self._set(threads)
        self.threads, self._windows_here = threads, 0
        self.switches += 1
        self._untold, self._last_why = self._untold + 1, why
        self._tell(self._clock())

    def _tell(self, now: float) -> None:
        """The switches not yet told, in one line, unless a line went out under REPORT_EVERY_S ago."""
        if self.report is None or not self._untold:
            return
        if self._told_at is not None and now - self._told_at < REPORT_EVERY_S:
            return
        head = f'torch threads {self.threads} (of {self.most})'
        if self._untold == 1:
            self.report(f'{head}: {self._last_why}')
        else:
            since = f' in the last {now - self._told_at:.0f} s' if self._told_at is not None else ''
            self.report(f'{head}, after {self._untold} switches{since} (the last: {self._last_why})')
        self._untold, self._told_at = 0, now


_governor: Optional[ThreadGovernor] = None
_fixed = False
_report: Optional[Callable[[str], None]] = None


def for_node(torch_threads: int, report: Callable[[str], None]) -> None:
    """A node's torch_threads: above 0, that many threads for good (``fix``); 0, fitted to the
    machine as the updates run, each switch told to ``report`` (the node's logger)."""
    if torch_threads > 0:
        fix(torch_threads)
    else:
        report_to(report)


def report_to(report: Callable[[str], None]) -> None:
    """Tell ``report`` (a node's logger) of each switch of the process's governor, in one line."""
    global _report
    _report = report
    if _governor is not None:
        _governor.report = report


def fix(threads: int) -> None:
    """torch's thread count set to ``threads`` for good (a node's torch_threads > 0): no governor."""
    global _fixed
    _fixed = True
    torch.set_num_threads(threads)


def adapt() -> None:
    """After each update (updater.py): the process's governor looks, made on the first call from
    torch's thread count then. A no-op once fixed or standing down."""
    global _governor
    if _fixed:
        return
    if _governor is None:
        _governor = ThreadGovernor(torch.get_num_threads(), report=_report)
    _governor.tick()


def most() -> int:
    """The most threads torch gets here: the governor's full count (whatever it has now), else
    torch's count. What a compiled program's fused kernels are built for (compiled_update.py)."""
    active = governor()
    return active.most if active is not None and not active.standing_down else torch.get_num_threads()


def governor() -> Optional[ThreadGovernor]:
    """The process's governor (None before the first update, or when fixed)."""
    return None if _fixed else _governor
