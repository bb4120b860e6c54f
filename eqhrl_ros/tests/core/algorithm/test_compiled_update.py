"""compile_update: the whole update as one compiled program, off the acting path.

The compiled update must compute what the eager update computes (same draws, same order,
float rounding apart), compile without holding up the updates that run meanwhile, and fall
back to the eager update with one log line when the compiler fails or cannot be used.
"""

from __future__ import annotations

import signal
import subprocess
import threading

import numpy as np
import pytest
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.algorithm import compiled_update as compiled
from eqhrl_ros.core.algorithm import equations as eq
from eqhrl_ros.core.algorithm import update
from eqhrl_ros.core.data.weights import apply_weights, encode_weights

# Small networks: the program's size (and so the compile time) does not depend on the widths.
SMALL = {'hidden': (32, 32), 'batch_size': 32, 'learning_starts': 1, 'seed': 3}


class Lines:
    """A logger that keeps its lines (what a ROS node's logger would print)."""

    def __init__(self):
        self.info_lines, self.warning_lines = [], []

    def info(self, line):
        self.info_lines.append(line)

    def warning(self, line):
        self.warning_lines.append(line)


def filled(transitions: int = 200, advised_every: int = 0, **overrides) -> EQSACLearner:
    learner = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(**{**SMALL, **overrides}))
    rng = np.random.default_rng(0)
    for i in range(transitions):
        learner.store(
            rng.normal(size=3),
            rng.uniform(-1, 1, size=1),
            float(rng.normal()),
            rng.normal(size=3),
            bool(i % 50 == 49),
            advised=bool(advised_every) and i % advised_every == 0,
        )
    return learner


def largest_difference(a: EQSACLearner, b: EQSACLearner) -> float:
    pairs = [
        *zip(a.actor.state_dict().values(), b.actor.state_dict().values()),
        *zip(a.critic.state_dict().values(), b.critic.state_dict().values()),
        *zip(a.critic_target.state_dict().values(), b.critic_target.state_dict().values()),
        (a.log_alpha.detach(), b.log_alpha.detach()),
    ]
    return max(float((x - y).abs().max()) for x, y in pairs)


@pytest.mark.slow  # the compiler: about a minute on 2 cores with a cold cache
def test_the_compiled_update_computes_what_the_eager_update_computes():
    """EQSAC with the actor also trained on advice: first updates without advice (SAC's update),
    then with D_advising filled, so both compiled variants are checked against the eager update."""
    settings = {'mode': 'eqsac', 'actor_on_advice': True}
    eager, fast = filled(**settings), filled(compile_update=True, **settings)
    log = Lines()
    fast.log = log
    eager.update(), fast.update()  # eager, both; the second one starts the compiler
    assert isinstance(fast.compiled_update, compiled.CompiledUpdate)
    assert fast.compiled_update.wait(timeout=900), fast.compiled_update.failed
    assert len(log.info_lines) == 1 and 'compiled' in log.info_lines[0] and not log.warning_lines

    for _ in range(5):
        expected, got = eager.update(), fast.update()
        assert 'advice_critic_loss' not in got  # D_advising is still empty
    for learner in (eager, fast):  # advice arrives: the second critic step and the actor on advice
        for i in range(40):
            learner.store([0.1 * i, 0.0, 1.0], [0.5], 1.0, [0.1 * i, 0.1, 1.0], False, advised=True)
    for _ in range(20):
        expected, got = eager.update(), fast.update()
    assert set(got) == set(expected)
    for name in expected:
        assert got[name] == pytest.approx(expected[name], rel=1e-4, abs=1e-5), name
    assert largest_difference(eager, fast) < 1e-4
    assert fast.updates == eager.updates == 26
    # The optimisers' own state moved with the compiled steps (checkpoints save it): with advice,
    # two critic steps and two actor steps per update.
    for a, b in (
        (eager.updater.optimizers['critic'], fast.updater.optimizers['critic']),
        (eager.updater.optimizers['actor'], fast.updater.optimizers['actor']),
    ):
        for p, q in zip(a.param_groups[0]['params'], b.param_groups[0]['params']):
            assert float(b.state[q]['step']) == float(a.state[p]['step']) == 1 + 5 + 2 * 20
            torch.testing.assert_close(b.state[q]['exp_avg_sq'], a.state[p]['exp_avg_sq'], rtol=1e-3, atol=1e-7)
    # The random streams were drawn in the eager update's order: the next draws agree.
    assert torch.equal(eager.streams.noise((4,), 'update'), fast.streams.noise((4,), 'update'))


@pytest.mark.slow  # the compiler
def test_a_checkpoint_loaded_into_a_compiled_learner_is_what_it_updates():
    """Loading a state replaces the learner's modules and optimisers: the compiled update must
    then step the loaded weights, as the eager update does."""
    eager, fast = filled(mode='sac'), filled(mode='sac', compile_update=True)
    fast.log = Lines()
    eager.update(), fast.update()
    assert fast.compiled_update.wait(timeout=900), fast.compiled_update.failed
    donor = filled(mode='sac', seed=11)
    for _ in range(3):
        donor.update()
    for learner in (eager, fast):
        learner.load_state_dict(donor.state_dict())
    assert largest_difference(eager, fast) == 0.0
    for _ in range(5):
        expected, got = eager.update(), fast.update()
    assert got['critic_loss'] == pytest.approx(expected['critic_loss'], rel=1e-4)
    assert largest_difference(eager, fast) < 1e-5
    assert largest_difference(donor, fast) > 1e-4  # it learned from the loaded weights on
    # A state saved before any update holds no Adam moments: the next update runs eagerly and
    # makes them, then the compiled ones go on (before, the update raised KeyError 'exp_avg').
    newborn = filled(mode='sac', seed=12)
    for learner in (eager, fast):
        learner.load_state_dict(newborn.state_dict())
    for _ in range(3):
        expected, got = eager.update(), fast.update()
    assert got['critic_loss'] == pytest.approx(expected['critic_loss'], rel=1e-4)
    assert largest_difference(eager, fast) < 1e-5 and fast.updates == eager.updates


@pytest.mark.slow  # the compiler, twice
def test_a_change_of_torchs_thread_count_never_compiles_on_the_learners_thread(monkeypatch):
    """cpu_threads.py switches torch between one thread and every thread as the machine gets busy
    or free. Each switch failed the program's guard on torch's global state and compiled the
    update again, on the learner's own thread (seconds to a minute). Now the program built for
    every thread serves any count at once, and the first switch to one thread starts, in the
    background, a program built for one (whose kernels leave the crowded cores alone); every
    program computes what the eager update computes."""
    from eqhrl_ros.core.algorithm import cpu_threads

    monkeypatch.setattr(cpu_threads, '_fixed', True)  # the counts are set by hand here
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        eager, fast = filled(mode='sac'), filled(mode='sac', compile_update=True)
        fast.log = Lines()
        eager.update(), fast.update()
        compiled_update = fast.compiled_update
        assert compiled_update.wait(timeout=900), compiled_update.failed
        assert compiled_update.threads == 2 and compiled_update.one_thread is None

        def both_update(count):
            torch.set_num_threads(count)
            expected, got = eager.update(), fast.update()
            assert got['critic_loss'] == pytest.approx(expected['critic_loss'], rel=1e-4), count

        with torch.compiler.set_stance('fail_on_recompile'):  # a compile again of a program raises
            both_update(2)
        # The first update at one thread runs the program for every thread, as it is (one entry in
        # its code's cache: a compile again would add one), and starts the one for one thread in
        # the background (a first compile, which the stance above would refuse too).
        both_update(1)
        assert len(cache_entries(compiled_update.function)) == 1
        one = compiled_update.one_thread
        assert one is not None and one.threads == 1
        assert one.wait(timeout=900), one.failed
        assert 'for one thread' in fast.log.info_lines[-1]
        with torch.compiler.set_stance('fail_on_recompile'):
            for count in (2, 1, 2, 1):
                both_update(count)
                assert compiled_update.program() is (one.function if count == 1 else compiled_update.function)
        assert len(cache_entries(compiled_update.function)) == len(cache_entries(one.function)) == 1
    finally:
        torch.set_num_threads(threads)
    assert largest_difference(eager, fast) < 1e-5


def cache_entries(program) -> list:
    """The programs dynamo keeps for a torch.compile'd function (one per guard set it compiled)."""
    from torch._dynamo.eval_frame import _debug_get_cache_entry_list

    return _debug_get_cache_entry_list(program._torchdynamo_orig_callable.__code__)


@pytest.mark.slow  # the compiler, twice
def test_learners_that_differ_only_in_a_constant_get_a_program_each():
    """The programs are shared by every learner in a process, and most of their guards are
    dropped (compiled_update.keep_guard): the constants baked into a program (gamma here) must
    still tell two learners apart, or the second would learn with the first one's gamma."""
    pairs = []
    for gamma in (0.99, 0.5):
        eager, fast = filled(mode='sac', gamma=gamma), filled(mode='sac', gamma=gamma, compile_update=True)
        fast.log = Lines()
        eager.update(), fast.update()
        assert fast.compiled_update.wait(timeout=900), fast.compiled_update.failed
        pairs.append((eager, fast))
    for eager, fast in pairs:
        for _ in range(3):
            expected, got = eager.update(), fast.update()
        assert got['critic_loss'] == pytest.approx(expected['critic_loss'], rel=1e-4)
        assert largest_difference(eager, fast) < 1e-5


def test_the_guards_kept_are_those_on_the_data_and_torchs_state():
    for name in ('batch[0]', 'advice', 'noise[2]', "constants['gamma']", "weights['actor']['heads.weight']", ''):
        assert compiled.keep_guard(name, is_global=False), name
    for name in ('nets[0].action_dim', "nets[1]._modules['biases']", "__import__('torch').utils._pytree"):
        assert not compiled.keep_guard(name, is_global=False), name
    assert not compiled.keep_guard("G['torch']", is_global=True)
    # torch's global state as a whole holds the thread count, which cpu_threads.py changes: dropped;
    # grad mode and the others keep guards of their own.
    assert not compiled.keep_guard('', is_global=False, guard_type='GLOBAL_STATE')
    for kind in ('GRAD_MODE', 'DETERMINISTIC_ALGORITHMS', 'TORCH_FUNCTION_STATE', 'DEFAULT_DEVICE'):
        assert compiled.keep_guard('', is_global=False, guard_type=kind), kind
    # Every argument of the program's function (and of the update it calls) but the modules is
    # guarded: a new argument must be added.
    for function in (update.update_then_act, update.algorithm1_update):
        arguments = function.__code__.co_varnames[: function.__code__.co_argcount]
        assert set(arguments) - set(compiled.GUARDED_ARGUMENTS) == {'nets'}, function.__name__


@pytest.mark.slow  # the compiler (once: the other learners find its program)
def test_learners_started_together_in_one_process_all_get_the_compiled_update():
    """Five learners of one setting start compiling at once. Before, each background thread
    missed the program the others were compiling and compiled it again; two of the five went
    past dynamo's limit of 8 programs per function and stayed eager."""
    settings = {'mode': 'eqsac', 'actor_on_advice': True, 'advised_every': 3}
    learners = [filled(compile_update=True, **settings) for _ in range(5)]
    logs = []
    for learner in learners:
        learner.log = Lines()
        logs.append(learner.log)
        learner.update()
    assert all(learner.compiled_update.wait(timeout=900) for learner in learners), [
        learner.compiled_update.failed for learner in learners
    ]
    assert not any(log.warning_lines for log in logs)
    eager = filled(**settings)
    eager.update()
    for _ in range(3):
        expected, got = eager.update(), learners[-1].update()
    assert got['advice_critic_loss'] == pytest.approx(expected['advice_critic_loss'], rel=1e-4)


def test_each_setting_gets_a_function_of_its_own_and_learners_of_one_setting_share_it(monkeypatch):
    """Dynamo keeps at most 8 programs per function: a ninth learner of another setting in one
    process failed to compile. Each setting now has its own copy of the update function."""
    compiled_functions = []

    def recording(function, **options):
        compiled_functions.append(function)
        return lambda *args: None

    monkeypatch.setattr(compiled.torch, 'compile', recording)
    for gamma in (0.9, 0.9, 0.5):
        learner = filled(mode='sac', gamma=gamma, compile_update=True)
        learner.update()
        learner.compiled_update.wait(timeout=60)
    same, again, other = compiled_functions
    assert same is again and other is not same
    # (dynamo keeps its programs on the code object itself: equal code, distinct objects)
    codes = [update.update_then_act.__code__, same.__code__, other.__code__]
    assert len({id(code) for code in codes}) == 3


class SlowCompiler:
    """torch.compile's stand-in: the 'compiled' function is the eager function, and the first
    (warm-up) call waits until the test lets it go, as a slow compiler would."""

    def __init__(self):
        self.release = threading.Event()
        self.calls = 0

    def __call__(self, function, **options):
        def run(*args):
            self.release.wait(60)
            self.calls += 1
            return function(*args)

        return run


def test_updates_go_on_eagerly_while_the_compiler_works_and_use_it_once_it_is_done(monkeypatch):
    compiler = SlowCompiler()
    monkeypatch.setattr(compiled.torch, 'compile', compiler)
    learner = filled(mode='sac', compile_update=True)
    learner.log = Lines()
    learner.update()
    thread = learner.compiled_update._thread
    for _ in range(3):  # the compiler is still busy: these updates are eager and do not wait for it
        learner.update()
    assert thread.is_alive() and not learner.compiled_update.ready and compiler.calls == 0
    compiler.release.set()
    assert learner.compiled_update.wait(timeout=60)
    assert compiler.calls == 1  # the warm-up, on copies
    learner.update()
    assert compiler.calls == 2 and learner.updates == 5


def test_a_failing_compiler_leaves_the_eager_update_and_says_so_once(monkeypatch):
    def broken(function, **options):
        def run(*args):
            raise RuntimeError('no C++ compiler found\nmore detail')

        return run

    monkeypatch.setattr(compiled.torch, 'compile', broken)
    eager, learner = filled(mode='eqsac'), filled(mode='eqsac', compile_update=True)
    learner.log = log = Lines()
    eager.update(), learner.update()
    assert not learner.compiled_update.wait(timeout=60)
    assert log.warning_lines == [
        'compile_update: the compiler failed (RuntimeError: no C++ compiler found); '
        'the learner stays with the eager update'
    ]
    for _ in range(3):
        assert learner.update() == eager.update()
    assert largest_difference(eager, learner) == 0.0
    assert len(log.warning_lines) == 1 and not log.info_lines


@pytest.mark.parametrize(
    'signal_number, stopped', [(signal.SIGINT, True), (signal.SIGTERM, True), (signal.SIGKILL, False)]
)
def test_a_compiler_stopped_by_ctrl_c_is_not_called_failed(monkeypatch, signal_number, stopped):
    """A terminal's Ctrl-C reaches the compiler's g++ too (the whole process group): inductor
    then raises what it raises for a C++ error. The node is ending; its log says what stopped
    the compiler, at INFO, and blames no one. A compiler killed otherwise (the kernel's
    out-of-memory killer: SIGKILL) is a failure, and a WARNING says so."""
    from torch._inductor.exc import CppCompileError, InductorError

    def killed(function, **options):
        def run(*args):
            try:
                try:
                    raise subprocess.CalledProcessError(-signal_number, ['g++', 'header.hpp'], b'')
                except subprocess.CalledProcessError as g_plus_plus:
                    raise CppCompileError(['g++', 'header.hpp'], '') from g_plus_plus
            except CppCompileError as error:
                raise InductorError(error, None) from None

        return run

    monkeypatch.setattr(compiled.torch, 'compile', killed)
    log = Lines()
    program = compiled.CompiledUpdate(filled(mode='eqsac').updater, log=log, background=False)
    assert not program.ready and program.failed == 'InductorError: CppCompileError: C++ compile error'
    name = signal.Signals(signal_number).name
    if stopped:
        assert log.info_lines == [
            f'compile_update: {name} stopped the C++ compiler; the learner stays with the eager update'
        ]
        assert log.warning_lines == []
    else:
        assert log.warning_lines == [
            'compile_update: the compiler failed (InductorError: CppCompileError: C++ compile error); '
            'the learner stays with the eager update'
        ]
        assert log.info_lines == []


def test_a_configuration_that_cannot_be_compiled_stays_eager_with_one_line():
    learner = filled(mode='eqsac', advice_batch='proportional', compile_update=True, advised_every=3)
    learner.log = log = Lines()
    for _ in range(3):
        learner.update()
    assert learner.compiled_update is None and learner.updater.compile_refused and learner.updates == 3
    assert log.warning_lines == [
        "compile_update: advice_batch 'proportional' changes the batch size at every step; "
        'the learner stays with the eager update'
    ]


def test_compile_update_is_off_by_default_and_a_learner_parameter():
    learner = filled()
    learner.update()
    assert learner.config.compile_update is False and learner.compiled_update is None
    with pytest.raises(ValueError, match='compile_update must be true or false'):
        LearnerConfig(compile_update='yes')


def test_an_eager_update_while_a_compile_runs_elsewhere_stays_eager(monkeypatch):
    """torch.compiler.is_compiling() is one flag for the whole process, true while a compile runs
    in any thread. compile_update compiles in the background while the eager updates go on: an
    eager update that read the flag took the compiled path's Adam (capturable), which fails on
    the CPU outside a compiled program, and ended a study run. Here the flag is set as a
    background compile sets it."""
    eager, during = filled(mode='eqsac', advised_every=3), filled(mode='eqsac', advised_every=3)
    eager.update(), during.update()
    monkeypatch.setattr(torch.compiler, '_is_compiling_flag', True)
    assert torch.compiler.is_compiling()
    for _ in range(3):
        got = during.update()
    monkeypatch.setattr(torch.compiler, '_is_compiling_flag', False)
    for _ in range(3):
        expected = eager.update()
    assert got == expected and largest_difference(eager, during) == 0.0


def test_the_networks_work_in_one_thread_while_fx_traces_in_another():
    """While compile_update compiles in its thread, inductor traces small functions with
    torch.fx.symbolic_trace, and fx patches nn.Module.__call__ for every thread meanwhile: a module
    called in another thread then raised NameError('module is not installed as a submodule'). A
    trainer making its owed updates died so in a real launch (`update failed: NameError(...)`).
    Here the patch is held open on purpose, and the learner acts, judges and updates through it."""
    learner = filled(mode='eqsac')
    inside, release = threading.Event(), threading.Event()

    def held(x):  # traced: fx's patch stays on until it returns
        inside.set()
        release.wait(30)
        return x

    tracer = threading.Thread(target=torch.fx.symbolic_trace, args=(held,), daemon=True)
    tracer.start()
    try:
        assert inside.wait(30)
        proposal = learner.propose(np.zeros(3))  # the actor, the twin critics' D(s), E(s)
        info = learner.update()
        assert np.isfinite(proposal.action).all() and np.isfinite(info['critic_loss'])
    finally:
        release.set()
        tracer.join(30)


def test_the_compiled_adam_step_is_torchs_with_each_networks_bias_corrections_computed_once():
    from torch._inductor.utils import run_and_get_code
    from torch.optim.adam import adam as torchs_adam

    from eqhrl_ros.core.algorithm.update import adam_

    settings = {'lr': 3e-3, 'betas': (0.9, 0.999), 'eps': 1e-8}
    shapes = [(2, 8, 16), (2, 1, 16), (2, 16, 1)]

    def weights_and_state(seed):
        generator = torch.Generator().manual_seed(seed)
        params = [torch.randn(shape, generator=generator) for shape in shapes]
        state = (
            [torch.zeros(s) for s in shapes],
            [torch.zeros(s) for s in shapes],
            [torch.tensor(7.0) for _ in shapes],
        )
        return params, state

    def torchs(params, grads, state):  # torch's own, as the compiled update traced it before
        torchs_adam(
            params,
            grads,
            *state[:2],
            [],
            state[2],
            foreach=False,
            capturable=True,
            amsgrad=False,
            beta1=0.9,
            beta2=0.999,
            lr=3e-3,
            weight_decay=0.0,
            eps=1e-8,
            maximize=False,
        )

    ours_compiled = torch.compile(lambda p, g, s: adam_(p, g, s, settings), fullgraph=True)
    torchs_compiled = torch.compile(torch.no_grad()(torchs), fullgraph=True)
    ours, reference = weights_and_state(0), weights_and_state(0)
    codes = []
    for step in range(3):
        grads = [torch.randn(shape, generator=torch.Generator().manual_seed(10 + step)) for shape in shapes]
        _, code = run_and_get_code(ours_compiled, ours[0], grads, ours[1])
        codes += code
        torchs_compiled(reference[0], grads, reference[1])
    for a, b in zip(
        [*ours[0], *ours[1][0], *ours[1][1], *ours[1][2]],
        [*reference[0], *reference[1][0], *reference[1][1], *reference[1][2]],
    ):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)
    assert float(ours[1][2][0]) == 10.0
    # Each power of a beta once per network (in the kernel of the corrections), not once per
    # weight (torch's traced form: in every chunk of every weight's loop).
    assert codes and max(c.count('std::pow') for c in codes) <= 2, [c.count('std::pow') for c in codes]


def test_the_compiled_tanh_is_tanh_to_float_rounding_with_tanhs_gradient_and_no_vector_tanh():
    from torch._inductor.utils import run_and_get_code

    from eqhrl_ros.core.algorithm import networks

    x = torch.cat([torch.linspace(-12.0, 12.0, 20001), torch.logspace(-30, 0, 301), -torch.logspace(-30, 0, 301)])
    x.requires_grad_(True)
    y = networks._ExpTanh.apply(x)
    assert float((y.double() - torch.tanh(x.detach().double())).abs().max()) < 2e-7
    y.sum().backward()
    torch.testing.assert_close(x.grad, 1.0 - torch.tanh(x.detach()) ** 2, rtol=1e-6, atol=1e-6)

    batch = torch.randn(64, networks.NUMPY_TANH_FROM // 64) * 3  # a batch: the compiled form applies
    compiled, code = run_and_get_code(torch.compile(networks.tanh, fullgraph=True), batch)
    assert float((compiled.double() - torch.tanh(batch.double())).abs().max()) < 2e-7
    assert code and not any('.tanh()' in c or 'std::tanh' in c for c in code)  # Sleef's tanh: twice the time


def eager_proposal(learner: EQSACLearner, obs) -> tuple:
    """What the eager propose computes for ``obs`` with the learner's weights now and the 'act'
    stream's next draw: (action in env units, D(s), E(s), the stream's state after that draw)."""
    generator = torch.Generator()
    generator.set_state(learner.streams.state_dict()['act'])  # as before any draw made ahead
    with torch.no_grad():
        obs_t = torch.as_tensor(np.asarray(obs, dtype=np.float32))[None]
        mean, log_std = learner.actor(obs_t)
        action = eq.squashed_gaussian_action(mean, log_std, torch.randn(mean.shape, generator=generator))
        q1, q2 = learner.critic(obs_t, action)
        discrepancy, entropy = float(eq.q_discrepancy(q1, q2)), float(eq.policy_entropy(mean, log_std))
    return learner.scaler.to_env(action[0].numpy()), discrepancy, entropy, generator.get_state()


@pytest.mark.slow  # the compiler
def test_the_compiled_update_acts_ahead_and_propose_takes_it_only_where_it_holds(monkeypatch):
    """After a compiled update, propose() on the observation the step gave takes the action, D(s)
    and E(s) that the program computed from the weights it left: what the eager propose computes
    from the same weights and the 'act' stream's same draw, to float rounding, with the stream
    left where the eager one leaves it. For another observation, or after the weights changed, it
    computes them itself, from that same draw."""
    # The setting of the first test's compiled learner (actor_on_advice too): its program, compiled once.
    learner = filled(compile_update=True, mode='eqsac', actor_on_advice=True, advising_budget=10**6)
    learner.update()
    assert learner.compiled_update.wait(timeout=900), learner.compiled_update.failed
    taken = []
    original = learner.updater.acted_ahead
    monkeypatch.setattr(learner.updater, 'acted_ahead', lambda obs_t: taken.append(original(obs_t)) or taken[-1])
    other = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(**{**SMALL, 'seed': 8}))
    rng = np.random.default_rng(1)
    cases = ('the observation expected', 'another observation', 'weights changed since', 'the array changed in place')
    for case in cases:
        obs, next_obs = rng.normal(size=3), rng.normal(size=3).astype(np.float32)  # float32: the learner's own
        learner.step(obs, np.array([0.5]), 0.1, next_obs, False, False)
        if case == 'weights changed since':
            apply_weights(learner, encode_weights(other))
        if case == 'the array changed in place':
            next_obs += 0.5
        proposed = next_obs if case != 'another observation' else next_obs + 1e-3
        expected_action, expected_d, expected_e, expected_stream = eager_proposal(learner, proposed)
        proposal = learner.propose(proposed)
        assert (taken[-1] is not None) == (case == 'the observation expected'), case
        np.testing.assert_allclose(proposal.action, expected_action, rtol=1e-5, atol=1e-6, err_msg=case)
        assert proposal.decision.discrepancy == pytest.approx(expected_d, rel=1e-4, abs=1e-6), case
        assert proposal.decision.entropy == pytest.approx(expected_e, rel=1e-5, abs=1e-6), case
        assert torch.equal(learner.streams.state_dict()['act'], expected_stream), case
