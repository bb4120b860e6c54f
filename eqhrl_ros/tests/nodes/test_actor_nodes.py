"""Actor nodes and a trainer over ROS topics, in the test process.

Each actor has its own env (and expert) in a namespace of its own; all send to one trainer on
/transitions and take its weights from /weights, as on several machines."""

import array
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy

from eqhrl_interfaces.msg import PolicyWeights, TransitionAck, TransitionBatch
from eqhrl_ros.core.data.summary import EpisodeSummary
from eqhrl_ros.core.data.torch_files import safe_load
from eqhrl_ros.core.runs.checkpoint import CHECKPOINT_FORMAT
from eqhrl_ros.files.mcap_record import read_record
from eqhrl_ros.nodes import messages, trainer_msgs
from eqhrl_ros.nodes.actor_node import ActorNode
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.trainer_node import TrainerNode

from ros_helpers import params

ALGORITHM = dict(
    env_id='Pendulum-v1',
    mode='eqsac',
    hidden_sizes=[16, 16],
    batch_size=16,
    learning_starts=60,
    queue_length=3,
    advising_budget=2,
)


def add_actor(harness, ros_context, namespace, **extra):
    """gym_env, expert and actor in ``namespace``; returns the actor node."""
    harness.add(
        GymEnvNode(
            context=ros_context,
            namespace=namespace,
            parameter_overrides=params(max_episode_steps=30, seed=len(namespace)),
        )
    )
    harness.add(ExpertNode(context=ros_context, namespace=namespace, parameter_overrides=params(env_id='Pendulum-v1')))
    values = dict(ALGORITHM, advice_timeout_s=1.0, batch_transitions=10, flush_period_s=0.2)
    values.update(extra)
    return harness.add(ActorNode(context=ros_context, namespace=namespace, parameter_overrides=params(**values)))


def add_trainer(harness, ros_context, tmp_path, **extra):
    """A trainer for tests about learning, not trust: it hears any actor unless told whom (actors,
    key_file); test_a_trainer_told_nobody_refuses_to_start checks the closed default."""
    values = dict(ALGORITHM, output_dir=str(tmp_path / 'trainer'), weights_every_updates=5, checkpoint_every_episodes=0)
    if 'actors' not in extra and 'key_file' not in extra:
        values['accept_any_actor'] = True
    values.update(extra)
    return harness.add(TrainerNode(context=ros_context, parameter_overrides=params(**values)))


def test_a_trainer_told_nobody_refuses_to_start(ros_context, tmp_path):
    """Closed by default: without actors, key_file or accept_any_actor, a stranger on the graph
    could write into D, so the trainer does not start, and says what to give it."""
    values = dict(ALGORITHM, output_dir=str(tmp_path / 'trainer'))
    with pytest.raises(ValueError, match='takes transitions only from actors it knows'):
        TrainerNode(context=ros_context, parameter_overrides=params(**values))


def test_a_trainer_that_refuses_to_start_leaves_no_publisher_or_thread(ros_context, tmp_path):
    """Refused after its publishers were made (spaces that contradict env_id): before, the half-built
    trainer stayed on the graph with its weights and acknowledgement publishers, and its learning
    thread ran on, in any process that goes on (a test run's)."""
    import threading

    values = dict(ALGORITHM, output_dir=str(tmp_path / 'trainer'), accept_any_actor=True, observation_size=5)
    values.update(action_low=[-2.0], action_high=[2.0])
    probe = rclpy.create_node('probe', namespace='/refused_trainer', context=ros_context)
    try:
        with pytest.raises(ValueError, match='the parameters give'):
            TrainerNode(context=ros_context, namespace='/refused_trainer', parameter_overrides=params(**values))
        for topic in ('/weights', '/transitions_ack', '/refused_trainer/trainer/episode_stats'):
            publishers = probe.get_publishers_info_by_topic(topic)
            assert not [i for i in publishers if i.node_namespace == '/refused_trainer'], topic
        assert not any(t.name == 'trainer-updates' and t.is_alive() for t in threading.enumerate())
    finally:
        probe.destroy_node()


def batch_message(actor: str, sequence: int = 0, n: int = 5, advised: bool = False) -> TransitionBatch:
    """A well-formed TransitionBatch of n zero transitions on Pendulum's spaces."""
    return TransitionBatch(
        actor=actor,
        sequence=sequence,
        observation_size=3,
        action_low=[-2.0],
        action_high=[2.0],
        observations=[0.0] * 3 * n,
        next_observations=[0.0] * 3 * n,
        actions=[0.0] * n,
        rewards=[0.0] * n,
        terminated=[False] * n,
        advised=[advised] * n,
    )


def test_two_actors_feed_one_trainer_and_act_with_its_weights(harness, ros_context, tmp_path):
    actors = [add_actor(harness, ros_context, f'/a{i}') for i in range(2)]
    trainer = add_trainer(harness, ros_context, tmp_path, record=True)
    assert harness.spin_until(lambda: len(trainer.summaries) >= 8, timeout=90)
    # Learning runs in the trainer's own thread, at its own pace; the actors act meanwhile.
    assert harness.spin_until(
        lambda: trainer.learner.updates > 20 and all(a.weights_version and a.weights_applied >= 2 for a in actors),
        timeout=60,
    )

    by_actor = {}
    for row, actor in trainer.summaries:
        by_actor.setdefault(actor, []).append(row)
    assert sorted(by_actor) == ['/a0/actor', '/a1/actor']
    assert [row.episode for row, _ in trainer.summaries] == list(range(len(trainer.summaries)))
    assert trainer.trainer.sequences.lost == 0 and trainer.refused_batches == 0
    for actor in actors:
        assert actor.weights_applied >= 2 and actor.weights_version > 0
        assert actor.learner.updates == 0 and len(actor.learner.replay) == 0  # no learning in an actor
        assert actor.trainer_id == trainer.trainer_id
    # Advice reached D_advising through the batches' advised flags.
    assert trainer.learner.advice_total.given == len(trainer.learner.advice_replay) > 0
    # The budget (2 episodes) counts episodes over both actors: an actor asks only while both
    # its own count and the trainer's (sent with the weights) are inside it, so at most 2 of
    # each actor's episodes asked, whoever ran ahead.
    asked = [row.episode for row, _ in trainer.summaries if row.advice_asked]
    assert 0 < len(asked) <= 2 * len(actors)
    for actor in actors:
        # (An episode's index may jump mid-episode when the trainer's count arrives.)
        assert len([s for s in actor.summaries if s.advice_asked]) <= 2
    rows = (tmp_path / 'trainer' / 'episodes.csv').read_text().splitlines()
    assert rows[0].endswith(',actor') and rows[1].endswith('/actor')

    # record: true: every batch it stored, as it came, and every episode, in trainer/record.mcap.
    trainer.stop_learning()
    trainer.close()
    contents = read_record(tmp_path / 'trainer' / 'record.mcap')
    assert contents.complete, contents.problem
    batches = [m.message for m in contents.on('/transitions')]
    assert sum(len(b.rewards) for b in batches) == len(trainer.learner.replay)
    assert sum(sum(b.advised) for b in batches) == len(trainer.learner.advice_replay)
    stats = [m.message.episode for m in contents.on('/trainer/episode_stats')]
    assert stats == [row.episode for row, _ in trainer.summaries]


def test_a_trainer_at_max_episodes_ends_its_actors_run_and_nothing_is_called_lost(harness, ros_context, tmp_path):
    """The shipped launch with pendulum.yaml: the trainer stops learning at max_episodes. Its
    actors, as a learner at max_episodes, then stop acting and sending: not free-running on,
    sending a batch the trainer never stores every 2 s, and saying at Ctrl-C that it was lost.
    An actor that starts after the end hears it at its first batch."""
    actors = [add_actor(harness, ros_context, f'/e{i}') for i in range(2)]
    quick = dict(actor_silence_s=0.5, report_period_s=0.2)
    trainer = add_trainer(harness, ros_context, tmp_path, max_episodes=4, updates_per_transition=4.0, **quick)
    assert harness.spin_until(lambda: trainer.done and all(a.run_ended for a in actors), timeout=60)
    # Free-running actors outran the updates (4 a transition): the trainer makes those it owes, then
    # saves. Before, it stopped with them unmade, and its policy had had a fraction of Algorithm 1's.
    owed_at_the_end = trainer.trainer.updates_owed()
    assert harness.spin_until(lambda: not trainer.paying, timeout=60)
    assert owed_at_the_end > 0 and trainer.trainer.updates_owed() == 0
    assert trainer.learner.updates == int(4 * trainer.trainer.eligible) > 0
    saved = safe_load(tmp_path / 'trainer' / 'checkpoint.pt', CHECKPOINT_FORMAT)['counters']
    assert saved['updates'] == trainer.learner.updates  # the final save came after them
    stored, steps = trainer.learner.total_steps, [a.learner.total_steps for a in actors]
    sent = [a.sent_batches for a in actors]
    logger, said = trainer.get_logger(), []

    class Said:  # the trainer's info lines, kept as it says them
        def __getattr__(self, name):
            return getattr(logger, name)

        def info(self, line, **kw):
            said.append(line)
            logger.info(line, **kw)

    trainer.get_logger = lambda: Said()
    harness.spin_until(lambda: False, timeout=1.5)
    # Its periodic line (report_period_s 0.2) once more at most: not the same counts 7 times over.
    assert len([line for line in said if ' transitions from ' in line]) <= 1, said
    del trainer.get_logger
    assert [a.learner.total_steps for a in actors] == steps and [a.sent_batches for a in actors] == sent
    assert all(a.done for a in actors) and trainer.learner.total_steps == stored
    assert not trainer.silent_actors  # 1.5 s of silence past actor_silence_s: asked for, not news
    assert [c.message for c in trainer.health_checks() if c.name == 'actors'] == [
        'the run has ended (max_episodes): no batch is stored any more'
    ]
    for actor in actors:
        line = actor.report()
        assert "made after the trainer's run ended (not sent)" in line and 'lost' not in line, line

    late = add_actor(harness, ros_context, '/late')
    assert harness.spin_until(lambda: late.run_ended, timeout=30)
    assert trainer.learner.total_steps == stored and '/late/actor' not in trainer.trainer.sequences.actors


def test_a_trainer_stopped_while_making_its_owed_updates_saves_them_and_says_how_many_are_left(
    harness, ros_context, tmp_path
):
    """Ctrl-C (the node's on_exit) while the trainer makes the updates owed at max_episodes: the
    checkpoint holds every update made so far, and one line says how many were left unmade."""
    from eqhrl_ros.nodes.trainer_exit import stop_save_and_close

    add_actor(harness, ros_context, '/p0')
    trainer = add_trainer(harness, ros_context, tmp_path, max_episodes=2, updates_per_transition=100.0)
    assert harness.spin_until(lambda: trainer.paying and trainer.learner.updates > 10, timeout=60)
    logger, warned = trainer.get_logger(), []
    trainer.get_logger = lambda: SimpleNamespace(warn=warned.append, info=logger.info, error=logger.error)
    harness.nodes.remove(trainer)
    harness.executor.remove_node(trainer)
    stop_save_and_close(trainer)
    saved = safe_load(tmp_path / 'trainer' / 'checkpoint.pt', CHECKPOINT_FORMAT)['counters']
    left = trainer.trainer.updates_owed()
    assert saved['updates'] == trainer.learner.updates and left > 0
    assert [line.split(':')[0] for line in warned] == [
        f'stopped with {left} of the updates owed at max_episodes still unmade'
    ]
    trainer.destroy_node()


def test_a_resumed_trainer_whose_run_had_ended_stores_nothing_and_ends_its_actors_run(harness, ros_context, tmp_path):
    actor = add_actor(harness, ros_context, '/r0')
    first = add_trainer(harness, ros_context, tmp_path, max_episodes=2)
    assert harness.spin_until(lambda: first.done and actor.run_ended, timeout=60)
    stored = first.learner.total_steps
    first.stop_learning()
    first.close()
    harness.executor.remove_node(first)
    first.destroy_node()
    resumed = add_trainer(harness, ros_context, tmp_path, max_episodes=2, resume=True)
    assert resumed.done and resumed.learner.total_steps == stored
    late = add_actor(harness, ros_context, '/r1')
    assert harness.spin_until(lambda: late.run_ended, timeout=30)
    assert resumed.learner.total_steps == stored
    assert len((tmp_path / 'trainer' / 'episodes.csv').read_text().splitlines()) == 1 + 2


def test_a_strangers_acknowledgement_ending_the_run_beside_the_trainer_stops_no_actor(harness, ros_context, tmp_path):
    """Unsigned, an acknowledgement that ends the run is taken only while the trainer alone
    publishes acknowledgements: a stranger who copied the trainer's id beside it stops nothing."""
    actor = add_actor(harness, ros_context, '/s0')
    add_trainer(harness, ros_context, tmp_path)
    assert harness.spin_until(lambda: actor.trainer_id and actor.acks > 0, timeout=30)
    stranger = harness.add(rclpy.create_node('stranger', context=ros_context))
    forged = stranger.create_publisher(TransitionAck, '/transitions_ack', trainer_msgs.ACK_QOS)
    assert harness.spin_until(lambda: actor.count_publishers(actor.ack_topic) == 2, timeout=10)
    for _ in range(5):
        forged.publish(
            TransitionAck(
                trainer_id=actor.trainer_id,
                actor=actor.actor_name,
                actor_run=actor.actor_run,
                received_through=-1,
                saved_through=-1,
                highest_received=-1,
                run_ended=True,
            )
        )
        harness.spin_until(lambda: False, timeout=0.1)
    steps = actor.learner.total_steps
    assert harness.spin_until(lambda: actor.learner.total_steps > steps + 20, timeout=10)
    assert not actor.run_ended and not actor.done


def test_an_actor_keeps_its_transitions_until_a_trainer_listens(harness, ros_context, tmp_path):
    actor = add_actor(harness, ros_context, '/solo', queue_length=1)
    assert harness.spin_until(lambda: actor.learner is not None and actor.learner.total_steps >= 45, timeout=30)
    assert actor.sent_transitions == 0 and actor.outbox.waiting >= 40  # nobody to send to
    # With no trainer, it acts with the weights it has, and still asks for (and takes) advice.
    assert actor.learner.advice_total.given + actor.learner.episode_advice.given > 0
    trainer = add_trainer(harness, ros_context, tmp_path, queue_length=1)
    assert harness.spin_until(lambda: trainer.learner is not None and trainer.learner.total_steps >= 45, timeout=30)
    assert trainer.trainer.sequences.actors['/solo/actor'].lost == 0
    # Every transition the actor made reached the trainer, in order, the early ones too.
    assert harness.spin_until(lambda: trainer.learner.total_steps + actor.outbox.waiting >= actor.learner.total_steps)
    assert actor.outbox.dropped_transitions == 0


def test_bad_batches_and_bad_weights_are_refused_and_nothing_stops(harness, ros_context, tmp_path):
    actor = add_actor(harness, ros_context, '/x', advising_budget=0)
    trainer = add_trainer(harness, ros_context, tmp_path, weights_every_updates=1000)
    assert harness.spin_until(lambda: trainer.learner is not None and trainer.learner.total_steps >= 20, timeout=30)
    rogue = harness.add(rclpy.create_node('rogue', context=ros_context))
    batches = rogue.create_publisher(TransitionBatch, trainer_msgs.TRANSITIONS_TOPIC, trainer_msgs.TRANSITIONS_QOS)
    weights = rogue.create_publisher(PolicyWeights, trainer_msgs.WEIGHTS_TOPIC, trainer_msgs.WEIGHTS_QOS)
    assert harness.spin_until(lambda: batches.get_subscription_count() > 0 and weights.get_subscription_count() > 0)
    # Sizes that do not add up, and a NaN reward.
    batches.publish(
        TransitionBatch(
            actor='rogue',
            sequence=0,
            observation_size=3,
            action_low=[-2.0],
            action_high=[2.0],
            observations=[0.0] * 5,
            rewards=[0.0],
        )
    )
    nan = trainer_msgs.batch_msg(_one_transition_batch(np.nan), [-2.0], [2.0])
    batches.publish(nan)
    # Weights that are not safetensors, from a "new trainer".
    weights.publish(PolicyWeights(trainer_id='rogue', version=99, tensors=array.array('B', b'\x80\x04not weights')))
    steps = actor.learner.total_steps
    assert harness.spin_until(lambda: trainer.refused_batches == 2 and actor.weights_refused == 1, timeout=10)
    assert harness.spin_until(lambda: actor.learner.total_steps > steps + 20 and trainer.learner.total_steps > steps)
    assert actor.trainer_id == trainer.trainer_id  # still the real trainer's weights
    assert not np.isnan(trainer.learner.replay.reward[: len(trainer.learner.replay)].numpy()).any()


def _one_transition_batch(reward):
    from eqhrl_ros.core.data.transitions import Outbox

    outbox = Outbox('rogue', 3, 1, 1, 10)
    outbox.add([0.0, 0.0, 0.0], [0.0], reward, [0.0, 0.0, 0.0], False, False)
    return outbox.pop_oldest()


def test_actor_and_trainer_help_lists_their_parameters():
    from eqhrl_ros.cli.node_programs import help_text

    assert 'batch_transitions' in help_text('actor') and 'updates_per_transition' in help_text('trainer')


def test_actors_launch_file_gives_every_node_its_part_of_one_params_file(monkeypatch, tmp_path):
    """actors.launch.py run with stand-ins for the launch packages (not on PyPI): which nodes it
    starts, in which namespaces, with which parameters; every key of each params file's
    learner: section reaches the actor or the trainer, and each node accepts what it gets."""
    import importlib.util
    import sys
    import types

    from eqhrl_ros.parameters import ACTOR_NODE_PARAMS, LEARNER_CONFIG_PARAMS, TRAINER_PARAMS

    from ros_helpers import PARAMS_DIR

    arguments = {}

    class Config:
        def __init__(self, name):
            self.name = name

        def perform(self, context):
            return arguments[self.name]

    def fake(name, **attributes):
        module = types.ModuleType(name)
        module.__dict__.update(attributes)
        monkeypatch.setitem(sys.modules, name, module)

    fake('launch', LaunchDescription=list)
    fake(
        'launch.actions',
        DeclareLaunchArgument=lambda *a, **k: None,
        OpaqueFunction=lambda **k: None,
        RegisterEventHandler=lambda handler: ('on_exit', handler),
    )
    fake('launch.event_handlers', OnProcessExit=lambda **k: k)
    fake('launch.substitutions', LaunchConfiguration=Config)
    fake('launch_ros')
    fake('launch_ros.actions', Node=lambda **k: k)
    fake('ament_index_python')
    fake('ament_index_python.packages', get_package_share_directory=lambda name: str(PARAMS_DIR.parent))
    path = PARAMS_DIR.parent / 'launch' / 'actors.launch.py'
    spec = importlib.util.spec_from_file_location('actors_launch', path)
    launch_file = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(launch_file)

    accepted = {
        'actor': {p.name for p in (*LEARNER_CONFIG_PARAMS, *ACTOR_NODE_PARAMS)} | {'use_sim_time'},
        'trainer': {p.name for p in (*LEARNER_CONFIG_PARAMS, *TRAINER_PARAMS)} | {'use_sim_time'},
    }
    defaults = dict(actor_prefix='', actor_offset='0', resume='false', transitions_topic='/transitions', key_file='')
    defaults.update(overwrite='false', output_dir='')
    context = types.SimpleNamespace(argv=[], launch_configurations={})  # ros2 launch's command line, no namespace
    defaults.update(dds_profile='', use_sim_time='', env_node='')
    arguments.update(defaults, weights_topic='/weights', trainer_actors='')

    def launched():
        """The nodes, after checking that each has its handler: an error exit stops the launch."""
        result = launch_file._nodes(context, declared=[])
        nodes = [n for n in result if isinstance(n, dict)]
        handlers = [h for kind, h in (r for r in result if isinstance(r, tuple))]
        assert [h['target_action'] for h in handlers] == nodes
        with pytest.raises(RuntimeError, match='exited with code 1'):
            handlers[0]['on_exit'](types.SimpleNamespace(process_name='trainer-1', returncode=1), None)
        for normal in (0, -2, -15):  # an end, or the launch's own SIGINT and SIGTERM
            handlers[0]['on_exit'](types.SimpleNamespace(process_name='trainer-1', returncode=normal), None)
        return nodes

    for env in ('pendulum', 'lunar_lander', 'demo'):
        arguments.update(env=env, params_file='', actors='3', trainer='true', expert='true')
        nodes = launched()
        # The trainer hears the actors started here, and no one else.
        assert nodes[0]['parameters'][0]['actors'] == ['/actor0/actor', '/actor1/actor', '/actor2/actor']
        names = [(n.get('namespace', ''), n['executable']) for n in nodes]
        assert names[0] == ('', 'trainer')
        assert sorted(names[1:]) == sorted((f'actor{i}', e) for i in range(3) for e in ('gym_env', 'expert', 'actor'))
        import yaml

        learner = yaml.safe_load((PARAMS_DIR / f'{env}.yaml').read_text())['learner']['ros__parameters']
        given = {}
        for node in nodes:
            values = node['parameters'][0]
            if node['executable'] in accepted:
                assert set(values) <= accepted[node['executable']], (env, node['executable'])
                given.update(values)
        assert set(learner) <= set(given), set(learner) - set(given)  # nothing of the file is lost
        seeds = [n['parameters'][0]['seed'] for n in nodes if n['executable'] == 'actor']
        assert len(set(seeds)) == 3  # each actor its own noise; the env seeds differ likewise
    arguments.update(actors='2', trainer='false', expert='false')
    robot = launched()
    assert [n['executable'] for n in robot] == ['gym_env', 'actor', 'gym_env', 'actor']
    # A robot machine (no trainer here): names from its host, so two robots launched alike differ.
    import socket

    host = socket.gethostname().lower()
    assert all(n['namespace'].endswith(('_actor0', '_actor1')) and n['namespace'] != 'actor0' for n in robot)
    assert host.replace('-', '_').replace('.', '_')[:3] in robot[0]['namespace']
    # A second robot with an offset: other indices and seeds; remaps and resume reach the nodes.
    arguments.update(actor_prefix='team_b_', actor_offset='2', transitions_topic='/b/transitions', trainer='true')
    arguments.update(resume='true', key_file='/keys/deployment.key', expert='true')
    second = launched()
    keyed = [n['executable'] for n in second if n['parameters'][0].get('key_file') == '/keys/deployment.key']
    assert sorted(keyed) == ['actor', 'actor', 'expert', 'expert', 'trainer']  # the env nodes sign nothing
    assert second[0]['parameters'][0]['resume'] is True
    assert [n['namespace'] for n in second if n['executable'] == 'actor'] == ['team_b_2', 'team_b_3']
    assert [n['parameters'][0]['seed'] for n in second if n['executable'] == 'actor'] == [44, 45]
    assert all(('/transitions', '/b/transitions') in n['remappings'] for n in second if n['executable'] in accepted)
    assert all(n['additional_env'] == {} for n in second)  # no dds_profile: the environment as it is
    # dds_profile:=lossy_link: every node gets the shipped Fast DDS profile; a name that is no
    # profile and no file is refused.
    arguments.update(dds_profile='lossy_link')
    profiles = {n['additional_env']['FASTRTPS_DEFAULT_PROFILES_FILE'] for n in launched()}
    assert len(profiles) == 1 and profiles.pop().endswith('config/fastdds_lossy_link.xml')
    arguments.update(dds_profile='lossy')
    with pytest.raises(ValueError, match='dds_profile:=lossy is neither'):
        launch_file._nodes(context, declared=[])
    arguments.update(dds_profile='')
    # A trainer alone, told its actors on other machines by name.
    arguments.update(actors='0', trainer_actors='/host_a_actor0/actor, /host_b_actor0/actor', key_file='')
    (alone,) = launched()
    assert alone['parameters'][0]['actors'] == ['/host_a_actor0/actor', '/host_b_actor0/actor']
    arguments.update(trainer_actors='')
    (alone,) = launched()
    assert 'actors' not in alone['parameters'][0]  # so it refuses to start, and the launch exits non-zero
    # Actors that see: a camera in the learner: section reaches the actors; the trainer is told
    # no env (it takes its spaces and camera from their first batch).
    import yaml

    data = yaml.safe_load((PARAMS_DIR / 'pendulum.yaml').read_text())
    data['learner']['ros__parameters'].update(camera='camera', camera_stack=3, replay_capacity=100_000)
    data['gym_env']['ros__parameters'].update(camera='camera')
    (tmp_path / 'camera.yaml').write_text(yaml.safe_dump(data))
    arguments.update(params_file=str(tmp_path / 'camera.yaml'), actors='2', actor_offset='0', actor_prefix='')
    nodes = launched()
    by_kind = {}
    for node in nodes:
        by_kind.setdefault(node['executable'], []).append(node['parameters'][0])
    assert 'env_id' not in by_kind['trainer'][0] and by_kind['trainer'][0]['replay_capacity'] == 100_000
    assert all(
        a['camera'] == 'camera' and a['camera_stack'] == 3 and a['env_id'] == 'Pendulum-v1' for a in by_kind['actor']
    )
    assert all(e['camera'] == 'camera' for e in by_kind['gym_env'])


def test_weights_wait_steps_keeps_a_lock_step_actor_within_reach_of_the_trainer(harness, ros_context, tmp_path):
    """Without it a lock-step actor runs ahead of learning (docs/performance.md); with it, at
    most weights_wait_steps steps per weights message, and the actor acts on once they come."""
    trainer = add_trainer(harness, ros_context, tmp_path, weights_every_updates=5, advising_budget=0)
    actor = add_actor(harness, ros_context, '/paced', weights_wait_steps=10, advising_budget=0)
    assert harness.spin_until(
        lambda: (actor.weights_version or 0) > 0 and actor.transitions_pub.get_subscription_count() > 0, timeout=60
    )
    harness.spin_until(lambda: False, timeout=0.5)
    steps0, applied0 = actor.learner.total_steps, actor.weights_applied
    updates0, stored0 = trainer.learner.updates, trainer.learner.total_steps
    assert harness.spin_until(lambda: actor.learner.total_steps >= steps0 + 200, timeout=60)
    steps, applied = actor.learner.total_steps - steps0, actor.weights_applied - applied0
    assert actor.weights_waits > 0
    assert steps <= 10 * (applied + 1), (steps, applied)
    # About one update per two steps meanwhile (5 per message, 10 steps per message).
    updates, stored = trainer.learner.updates - updates0, trainer.learner.total_steps - stored0
    assert updates >= 0.3 * stored, (updates, stored)


def test_the_trainers_inbox_is_bounded_in_bytes_and_counts_what_it_drops(harness, ros_context, tmp_path):
    trainer = add_trainer(harness, ros_context, tmp_path, inbox_limit_mb=1.0)
    trainer.stop_learning()  # nothing is stored: the inbox only fills, as under a flood faster than updates
    # 9,000 transitions of 3 + 3 + 1 + 1 floats and 2 flags: about 0.31 MB a batch
    msg = batch_message('/flood', n=9_000)
    for sequence in range(10):
        msg.sequence = sequence
        trainer._on_batch(msg)
    assert len(trainer._inbox) == 3 and trainer.dropped_batches == 7
    assert trainer._inbox_bytes <= 1e6


def test_a_trainer_saves_once_for_all_the_episodes_it_stores_in_one_step(harness, ros_context, tmp_path, monkeypatch):
    """checkpoint_every_episodes 1, and forty one-episode batches waiting at once (what an actor
    sends a resumed trainer: all it kept): one save after the last of them, not forty. Each save
    writes checkpoint, replay and policy; saving after every stored episode left a resumed trainer
    80 episodes behind its actor after two minutes (test_actor_processes, in CI)."""
    trainer = add_trainer(
        harness, ros_context, tmp_path, checkpoint_every_episodes=1, save_replay=True, learning_starts=1000
    )
    trainer.stop_learning()  # the thread ends; the test takes its steps itself
    trainer._stopping.clear()
    saved_at = []  # transitions stored at each save
    save = trainer.save
    monkeypatch.setattr(trainer, 'save', lambda: (saved_at.append(trainer.learner.tally.total_steps), save())[1])
    for sequence in range(40):
        msg = batch_message('/a0/actor', sequence)
        summary = EpisodeSummary(sequence, 0.0, 5, 0, 0, 0, 0, 0, False, 5 * (sequence + 1), 0.2)
        msg.episodes = [messages.stats_msg(summary)]
        trainer._on_batch(msg)
    assert trainer._learn_step()
    assert len(trainer.summaries) == 40 and saved_at == [200]
    assert trainer.trainer.sequences.actors['/a0/actor'].saved_through == 39  # all of them in the checkpoint
    assert (tmp_path / 'trainer' / 'checkpoint.pt').exists()
    assert not trainer._learn_step() and saved_at == [200]  # nothing new (and no update owed): no save


def test_a_flood_from_an_actor_the_trainer_does_not_hear_never_reaches_its_inbox(harness, ros_context, tmp_path):
    """Refused where it arrives, by name (and by signature with a key_file): before, the inbox
    queued a stranger's batches up to inbox_limit_mb and its memory stayed up after."""
    trainer = add_trainer(harness, ros_context, tmp_path, actors=['/a0/actor'])
    trainer.stop_learning()  # nothing is stored: what is queued stays in the inbox
    msg = batch_message('/flood', n=9_000)
    for sequence in range(10):
        msg.sequence = sequence
        trainer._on_batch(msg)
    assert not trainer._inbox and trainer._inbox_bytes == 0 and trainer.refused_batches == 10
    trainer._on_batch(batch_message('/a0/actor'))  # the actor it hears is queued as before
    assert len(trainer._inbox) == 1 and trainer.dropped_batches == 0


def test_a_rogue_trainer_beside_the_real_one_changes_no_action(harness, ros_context, tmp_path):
    """A well-formed PolicyWeights with a trainer id of its own, whose actor always pushes +2,
    published at 20 Hz beside the real trainer: the actor refuses every one and keeps acting
    with the real trainer's weights. Before, it adopted the first within 8 ms."""
    import torch

    from eqhrl_ros.core import EQSACLearner, LearnerConfig
    from eqhrl_ros.core.data.weights import encode_weights

    actor = add_actor(harness, ros_context, '/a0')
    trainer = add_trainer(harness, ros_context, tmp_path)
    assert harness.spin_until(lambda: actor.trainer_id == trainer.trainer_id, timeout=60)

    rogue_learner = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(hidden=(16, 16)))
    with torch.no_grad():
        rogue_learner.actor.heads.bias.fill_(50.0)  # mean +50: tanh gives +1, the env's +2
    rogue = rclpy.create_node('rogue', context=ros_context)
    harness.add(rogue)
    pub = rogue.create_publisher(PolicyWeights, trainer_msgs.WEIGHTS_TOPIC, trainer_msgs.WEIGHTS_QOS)
    tensors = array.array('B', encode_weights(rogue_learner))
    rogue.create_timer(
        0.05,
        lambda: pub.publish(
            PolicyWeights(
                trainer_id='rogue',
                version=2**62,
                episodes=2**31,
                stamp=rogue.get_clock().now().to_msg(),
                tensors=tensors,
            )
        ),
    )
    refused_before = actor.weights_refused
    assert harness.spin_until(lambda: actor.weights_refused > refused_before + 20, timeout=30)
    assert actor.trainer_id == trainer.trainer_id and actor.learner.episode < 2**31
    obs = np.zeros(3, np.float32)
    assert not np.allclose(actor.learner.act(obs, deterministic=True), rogue_learner.act(obs, deterministic=True))


def test_two_nodes_under_one_actor_name_are_refused_by_the_trainer(harness, ros_context, tmp_path):
    """Two machines launched alike used to put two actors in /actor0: the trainer mixed their
    batches ('started again', 964 batches lost). Now it refuses that name's batches with one line."""
    trainer = add_trainer(harness, ros_context, tmp_path, env_id='Pendulum-v1')
    twins = [harness.add(rclpy.create_node('actor', namespace='/actor0', context=ros_context)) for _ in range(2)]
    pubs = [
        t.create_publisher(TransitionBatch, trainer_msgs.TRANSITIONS_TOPIC, trainer_msgs.TRANSITIONS_QOS) for t in twins
    ]
    assert harness.spin_until(
        lambda: len(trainer.get_publishers_info_by_topic(trainer_msgs.TRANSITIONS_TOPIC)) == 2, timeout=10
    )

    pubs[0].publish(batch_message('/actor0/actor'))
    pubs[1].publish(batch_message('/actor0/actor'))
    assert harness.spin_until(lambda: trainer.refused_batches >= 2, timeout=10)
    assert trainer.learner.total_steps == 0 and trainer.trainer.sequences.actors == {}


def test_with_a_shared_key_only_signed_batches_and_weights_are_taken(harness, ros_context, tmp_path):
    from eqhrl_ros.core.data.signing import Signer, new_key_file

    key = str(new_key_file(tmp_path / 'deployment.key'))
    actor = add_actor(harness, ros_context, '/a0', key_file=key)
    trainer = add_trainer(harness, ros_context, tmp_path, key_file=key)
    assert harness.spin_until(lambda: len(trainer.summaries) >= 2 and actor.weights_applied >= 1, timeout=90)
    assert trainer.refused_batches == 0 and actor.trainer_id == trainer.trainer_id

    stranger = harness.add(rclpy.create_node('stranger', context=ros_context))
    batches = stranger.create_publisher(TransitionBatch, trainer_msgs.TRANSITIONS_TOPIC, trainer_msgs.TRANSITIONS_QOS)
    weights = stranger.create_publisher(PolicyWeights, trainer_msgs.WEIGHTS_TOPIC, trainer_msgs.WEIGHTS_QOS)
    forged = batch_message('/a0/actor', sequence=10**5, advised=True)
    unsigned = trainer.refused_batches
    batches.publish(forged)
    trainer_msgs.sign_batch(forged, Signer(b'another key, not ours!!'))
    forged.sequence += 1
    batches.publish(forged)
    refused_weights = actor.weights_refused
    stolen = PolicyWeights(trainer_id=trainer.trainer_id, version=10**6, episodes=0, tensors=[0] * 8)
    weights.publish(trainer_msgs.sign_weights(stolen, Signer(b'another key, not ours!!')))
    assert harness.spin_until(
        lambda: trainer.refused_batches >= unsigned + 2 and actor.weights_refused > refused_weights, timeout=20
    )
    assert '/a0/actor' in trainer.trainer.sequences.actors and trainer.trainer.sequences.lost == 0
    assert actor.weights_version < 10**6


def test_a_trainer_told_its_actors_refuses_any_other(harness, ros_context, tmp_path):
    add_actor(harness, ros_context, '/a0')
    add_actor(harness, ros_context, '/stranger')
    trainer = add_trainer(harness, ros_context, tmp_path, actors=['/a0/actor'])
    assert harness.spin_until(lambda: len(trainer.summaries) >= 2 and trainer.refused_batches > 0, timeout=90)
    assert {actor for _, actor in trainer.summaries} == {'/a0/actor'}
    assert '/stranger/actor' not in trainer.trainer.sequences.actors


CAMERA = dict(camera='camera', camera_height=16, camera_width=16, camera_encoding='mono8')


def test_two_camera_actors_feed_one_trainer_that_learns_from_their_frames(harness, ros_context, tmp_path):
    """Actors that see: each batch carries its frames once (PNG) and each transition's stack by
    index; the trainer takes its camera from the first batch, holds the stacks the actors acted
    on though their batches arrive interleaved, and sends its encoder with the weights."""
    actors = []
    for i in range(2):
        namespace = f'/c{i}'
        env = params(max_episode_steps=30, seed=i, **CAMERA)
        harness.add(GymEnvNode(context=ros_context, namespace=namespace, parameter_overrides=env))
        expert = params(env_id='Pendulum-v1')
        harness.add(ExpertNode(context=ros_context, namespace=namespace, parameter_overrides=expert))
        values = dict(ALGORITHM, advice_timeout_s=1.0, batch_transitions=10, flush_period_s=0.2, replay_capacity=1000)
        values.update(camera='camera', camera_stack=2)
        actors.append(
            harness.add(ActorNode(context=ros_context, namespace=namespace, parameter_overrides=params(**values)))
        )
    seen = []  # the stacks each actor acted on, as its batches carried them
    for actor in actors:
        sent = actor.transitions_pub.publish
        actor.transitions_pub.publish = lambda msg, sent=sent: (seen.append(msg), sent(msg))[1]
    values = {k: v for k, v in ALGORITHM.items() if k != 'env_id'}  # its spaces and camera: from the first batch
    values.update(output_dir=str(tmp_path / 'trainer'), weights_every_updates=5, checkpoint_every_episodes=0)
    values.update(accept_any_actor=True, replay_capacity=1000)
    trainer = harness.add(TrainerNode(context=ros_context, parameter_overrides=params(**values)))
    assert harness.spin_until(
        lambda: (
            trainer.learner is not None and trainer.learner.updates > 10 and all(a.weights_applied >= 2 for a in actors)
        ),
        timeout=120,
    )
    learner = trainer.learner
    assert learner.observation.camera is not None and learner.observation.camera.stack_shape == (2, 16, 16, 1)
    assert trainer.refused_batches == 0 and trainer.trainer.sequences.lost == 0
    for actor in actors:  # the trainer's encoder reached the actors with the weights
        theirs = actor.learner.observation.encoder.state_dict()
        assert theirs.keys() == learner.observation.encoder.state_dict().keys() and actor.weights_version > 0
    # D holds, for every transition stored, the stack its actor acted on (batches interleaved).
    from eqhrl_ros.core.data.transitions import batch_from_fields

    sent_stacks = {}
    for msg in seen:
        batch = batch_from_fields(msg)[0]
        if not len(batch):  # episode ends alone: no transitions, no frames
            assert batch.frames is None and batch.episodes
            continue
        for state, stack in zip(batch.observations, batch.frames.observation_stacks()):
            sent_stacks[state.tobytes()] = stack
    memory, n = learner.replay, len(learner.replay)
    j = memory.next_frame[:n]
    held = memory._stack(j - 1, memory.episode_first[j % memory.slots])  # as sample() gathers a row's stack
    checked = 0
    for row in range(n):
        state = memory.vectors.obs[row].numpy().tobytes()
        if state in sent_stacks:
            assert np.array_equal(held[row].reshape(2, 16, 16), sent_stacks[state][..., 0])
            checked += 1
    assert checked == n > 60  # every one, from both actors' batches
