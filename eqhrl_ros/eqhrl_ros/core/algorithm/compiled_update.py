"""compile_update: Algorithm 1's update (update.algorithm1_update) as one compiled program,
which then acts ahead on the next observation (update.update_then_act, acting_ahead.py).

The eager update dispatches hundreds of small operations per update. torch.compile
(fullgraph=True) turns the same function, unchanged, into one program with everything around
the matrix products fused: gradients from torch.func, Adam as torch's functional Adam applied
in place to the learner's weights and to its optimisers' own moments and step counts.

What a user sees:
- The first updates run eagerly. The compiler runs in a background thread on copies of the
  weights, off the acting path; once it is done, the next update is the compiled one.
- Its cost in seconds is reported in one log line, as is any failure, after which the
  learner stays eager (a Ctrl-C that stopped the C++ compiler is named as such, not a
  failure). Nothing else changes: the learner draws the batches and the noise as for the
  eager update, so both compute the same numbers to float rounding
  (tests/core/algorithm/test_compiled_update.py).
"""

from __future__ import annotations

import copy
import logging
import signal
import subprocess
import threading
import time
import types
from typing import Any, Callable, Optional

import torch

from ..data.replay import Minibatch
from . import cpu_threads
from . import equations as eq
from .config import asks_for_advice
from .update import update_noise, update_then_act

LOG = logging.getLogger('eqhrl_ros.compile')


# --------------------------------------------------------------------------- the guards

# torch.compile checks, before every call, that the program still fits its inputs (its
# "guards"): about 1,350 checks for EQSAC's update, 0.39 ms a call, most of them on what
# cannot change between calls: the modules' structure (``nets``: their weights come from
# ``weights``, so the weights' shapes fix it) and the globals (this package's equations and
# torch's own functions). Kept: the guards on the data arguments (each tensor's shape, dtype,
# device and stride, which of advice and the advice noise is None, the hyperparameters baked
# into the program as constants, so two learners that differ only in gamma get two programs)
# and torch's global state (grad mode and the like). 140 checks, 0.2 ms a call
# (docs/performance.md).
GUARDED_ARGUMENTS = ('weights', 'state', 'batch', 'advice', 'noise', 'constants', 'advised', 'step', 'ahead')
# Dropped too: the guard on torch's "global state" as a whole, which includes the thread count.
# cpu_threads.py changes that count as the machine gets busy or free, and each change failed the
# guard and compiled the update again, on the learner's own thread (1.5 s with a warm cache, the
# whole compile's tens of seconds without: a stall a real-time robot would feel). Grad mode, the
# deterministic-algorithms flag, torch-function modes and the default device keep guards of their
# own. The products then run at the count of the moment; the fused kernels in OpenMP teams of the
# size they were built for (cpp.threads: the same numbers at any count, docs/performance.md). So a
# learner has a program built for the most threads it gets, and, once the governor first drops to
# one, a second built for one, compiled in the background (CompiledUpdate.program). Inductor's
# cpp.dynamic_threads, which would let one program's kernels follow the count, gave half the critic
# loss at 2 threads with torch 2.13 (tests/core/algorithm/test_compiled_update.py would catch it).
DROPPED_GUARD_TYPES = ('GLOBAL_STATE',)


def keep_guard(name: str, is_global: bool, guard_type: str = '') -> bool:
    """Whether a guard on ``name`` (its source, as dynamo writes it: "batch[0]",
    "constants['gamma']", "nets[0].action_dim", "G['torch']"; '' for torch's global state) of
    ``guard_type`` stays."""
    if is_global or guard_type in DROPPED_GUARD_TYPES:
        return False
    root = name.split('[', 1)[0].split('.', 1)[0]
    return root == '' or root in GUARDED_ARGUMENTS


def _guards_to_keep(entries) -> list:
    """torch.compile's guard_filter_fn."""
    return [keep_guard(entry.name, entry.is_global, entry.guard_type) for entry in entries]


# --------------------------------------------------------------------------- one program per setting

# Dynamo keeps the programs it compiles on the function's code object, at most 8 of them
# (torch._dynamo.config.recompile_limit); past that, a fullgraph compile fails. An updater needs
# one or two (with and without an advice batch), but a process with learners of several
# settings (a sweep, a benchmark) would pass 8. So each setting gets a copy of
# update_then_act with a code object of its own, shared by the learners of that setting.
_COPIES: dict = {}
_COPIES_LOCK = threading.Lock()
# One warm-up at a time in a process: learners started together would each miss the program
# that the first of them is compiling, and compile it again, up to the limit above.
_COMPILING = threading.Lock()


def update_function_for(setting) -> Callable:
    """update_then_act, the same copy for every learner whose ``setting`` (a hashable
    summary of what its program is specialised to) is equal."""
    with _COPIES_LOCK:
        function = _COPIES.get(setting)
        if function is None:
            original = update_then_act
            function = types.FunctionType(
                original.__code__.replace(), original.__globals__, original.__name__, original.__defaults__
            )
            function.__doc__, function.__qualname__ = original.__doc__, original.__qualname__
            _COPIES[setting] = function
        return function


# Inductor's options for the update's program, beside the thread count and the guard filter
# (compile_program); benchmarks/kernel_options.py measures others by changing these dicts.
# - loop_ordering_after_fusion off: with it, torch 2.11's inductor failed an assertion on this
#   program on CUDA; on the CPU it makes no difference in speed.
# - cpp_wrapper, on the CPU: the program's calls (its products and fused kernels, their buffers,
#   the checks of its inputs) made from C++ instead of from a generated Python function. In the
#   training loop, steps 1.00-1.04x as fast (SAC) and 1.03x (EQSAC); called alone, the same speed;
#   the same compile time (docs/performance.md, "The program's calls from C++"). Not measured on a
#   GPU: not used there.
PROGRAM_OPTIONS: dict[str, Any] = {'loop_ordering_after_fusion': False}
CPU_PROGRAM_OPTIONS: dict[str, Any] = {'cpp_wrapper': True}


def compile_program(function: Callable, threads: int, device_type: str = 'cpu') -> Callable:
    """torch.compile of ``function`` as the update's program is compiled: one graph, static
    shapes, fused kernels in OpenMP teams of ``threads``, the options above (after the thread
    count, so that a benchmark may set it too), the guards above."""
    options: dict[str, Any] = {
        'cpp.threads': threads,
        **PROGRAM_OPTIONS,
        **(CPU_PROGRAM_OPTIONS if device_type == 'cpu' else {}),
        'guard_filter_fn': _guards_to_keep,
    }
    return torch.compile(function, fullgraph=True, dynamic=False, options=options)


# --------------------------------------------------------------------------- the learner's side


class CompiledUpdate:
    """A learner's update compiled in the background; ``function`` is the program, to be
    called as update_then_act once ``ready`` (``program()`` picks it for torch's thread count).

    ``log``: where the one line about the compiler goes: info() with its cost, or warning() with
    why the learner stays eager. Python's logger 'eqhrl_ros.compile' by default; a node passes
    its ROS logger (rclpy's loggers have the same two methods).
    ``threads``: the OpenMP team size of the program's fused kernels (default: the most torch
    gets here, cpu_threads.most()).
    """

    def __init__(self, updater, log=None, background: bool = True, threads: Optional[int] = None, crowd: bool = False):
        self.updater = updater
        self.log = log or LOG
        self.ready = False
        self.failed = ''
        self.error: Optional[BaseException] = None
        self.seconds: Optional[float] = None
        self.threads = threads or cpu_threads.most()
        self.crowd = crowd  # the program for one thread, beside the learner's first (program())
        # The program for one thread, compiled in the background the first time the governor
        # drops to one (kernels built for more keep their OpenMP team, whose waiting worker then
        # fights the crowd for the cores: 37-44 updates/s against 119-124 beside a busy process).
        self.one_thread: Optional[CompiledUpdate] = None
        self._variants = self._advice_variants()
        weights, state, constants = updater.inputs()
        self.function = compile_program(
            update_function_for(self._setting(constants)), self.threads, torch.device(updater.device).type
        )
        # Copies: tracing in the background must not touch the weights the learner acts and learns with.
        copies = (copy.deepcopy(updater.nets), _clone(weights), _clone(state), constants)
        if background:
            self._thread: Optional[threading.Thread] = threading.Thread(target=self._warm_up, args=copies, daemon=True)
            self._thread.start()
        else:
            self._thread = None
            self._warm_up(*copies)

    def _setting(self, constants: dict) -> tuple:
        """What the program is specialised to: the shapes, the device, the variants and the
        constants. (Its guards check all of it again; this only keeps the settings apart.)"""
        updater, cfg = self.updater, self.updater.config
        shapes = (updater.obs_dim, updater.action_dim, tuple(cfg.hidden), cfg.batch_size)
        variants = (
            cfg.actor_on_advice,
            tuple(self._variants),
            self.threads,
            updater.ahead.enabled,
            updater.ahead.flags,
        )
        return (*shapes, str(updater.device), *variants, repr(constants))

    def program(self) -> Callable:
        """The program for torch's thread count now (once ``ready``): at one thread, the one built
        for one thread once its background compile is done (started here the first time); else
        this one, which computes the same numbers at any count."""
        if self.threads > 1 and torch.get_num_threads() == 1:
            if self.one_thread is None:
                self.one_thread = CompiledUpdate(self.updater, self.log, background=True, threads=1, crowd=True)
            elif self.one_thread.ready:
                return self.one_thread.function
        return self.function

    def _advice_variants(self) -> list:
        """Whether an update has an advice batch, for every kind of update this learner makes."""
        cfg = self.updater.config
        if not asks_for_advice(cfg.mode) or not cfg.dual_replay:
            return [False]
        return [False, True]

    def _warm_up(self, nets, weights, state, constants) -> None:
        start = time.perf_counter()
        try:
            with _COMPILING:
                self._compile(nets, weights, state, constants)
        except Exception as error:  # noqa: BLE001 - any compiler failure leaves the eager update
            self.error = error  # the whole exception, for whoever wants more than the line
            self.failed = f'{type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ""}'
            stays = 'its program for every thread' if self.crowd else 'the eager update'
            stop = stopped_by(error)
            if stop in STOP_SIGNALS:  # a Ctrl-C or a launch's stop: not the compiler's fault
                self.log.info(f'compile_update: {stop} stopped the C++ compiler; the learner stays with {stays}')
            else:
                self.log.warning(f'compile_update: the compiler failed ({self.failed}); the learner stays with {stays}')
            return
        self.seconds = time.perf_counter() - start
        self.ready = True
        for_one = ' for one thread, as the machine is crowded' if self.crowd else ''
        self.log.info(
            f'compile_update: the whole update is compiled{for_one} ({self.seconds:.1f} s in the background; '
            f'{len(self._variants)} variant(s)); updates from now on run compiled'
        )

    def _compile(self, nets, weights, state, constants) -> None:
        """One call of each variant on made-up batches of the right shapes: the first call of a
        variant compiles it."""
        updater, size = self.updater, self.updater.config.batch_size
        device = updater.device

        def made_up_batch():
            return Minibatch(
                obs=torch.randn(size, updater.obs_dim, device=device),
                action=torch.rand(size, updater.action_dim, device=device) * 2 - 1,
                reward=torch.randn(size, device=device),
                next_obs=torch.randn(size, updater.obs_dim, device=device),
                terminated=torch.zeros(size, device=device),
            ).columns()

        eq.quadrature_nodes(torch.zeros((), device=device))  # E(s)'s nodes, made by numpy: before tracing
        for with_advice in self._variants:
            batch = made_up_batch()
            advice = made_up_batch() if with_advice else None
            sizes = [size] + ([size] if with_advice else [])
            noise = update_noise(
                lambda shape: torch.randn(shape, device=device),
                updater.action_dim,
                sizes,
                updater.config.actor_on_advice,
            )
            obs, act_noise = (
                torch.randn(1, updater.obs_dim, device=device),
                torch.randn(1, updater.action_dim, device=device),
            )
            ahead = (obs, act_noise, *updater.ahead.flags) if updater.ahead.enabled else None
            self.function(nets, weights, state, batch, advice, noise, constants, ahead)

    def wait(self, timeout: Optional[float] = None) -> bool:
        """Block until the background compile ended (tests, benchmarks); True if it is ready."""
        if self._thread is not None:
            self._thread.join(timeout)
        return self.ready


# A terminal's Ctrl-C goes to its whole process group, the compiler's g++ included, and `ros2
# launch` stops a node's group with SIGINT, then SIGTERM. The node ends then anyway; its log
# should not blame the compiler.
STOP_SIGNALS = ('SIGINT', 'SIGTERM')


def stopped_by(error: BaseException) -> Optional[str]:
    """The name of the signal that ended a compiler process behind ``error`` (inductor's
    InductorError holds a CppCompileError raised from g++'s CalledProcessError), if one did."""
    seen: set = set()
    cause: Optional[BaseException] = error
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, subprocess.CalledProcessError) and cause.returncode < 0:
            try:
                return signal.Signals(-cause.returncode).name
            except ValueError:
                return f'signal {-cause.returncode}'
        cause = getattr(cause, 'inner_exception', None) or cause.__cause__ or cause.__context__
    return None


def compiling() -> bool:
    """Whether a compile runs now, in any thread of this process (nodes/spinning.end_process)."""
    return _COMPILING.locked()


def _clone(value):
    """A copy of every tensor in nested dicts, tuples and lists."""
    if isinstance(value, torch.Tensor):
        return value.detach().clone()
    if isinstance(value, dict):
        return {k: _clone(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return type(value)(_clone(v) for v in value)
    return value
