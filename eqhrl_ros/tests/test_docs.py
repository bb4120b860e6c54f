"""The package README documents every declared parameter and every topic field."""

from pathlib import Path

import pytest

from eqhrl_ros.cli.node_programs import NODES, node_tables
from eqhrl_ros.core.data.signing import CommandSeal, Signer
from eqhrl_ros.experiments import seed_runs
from eqhrl_ros.nodes import messages

README = (Path(__file__).resolve().parents[1] / 'README.md').read_text()


TABLED = [(title, param) for name in NODES for title, params in node_tables(name) for param in params]


def test_every_parameter_is_a_row_of_its_nodes_readme_table():
    """Each node's parameter is a row of that node's table (tools/update_param_tables.py);
    one test that names every missing row at once."""

    def section(title):
        start = README.index(f'#### {title}\n')
        return README[start : README.index('\n#', start + 5)]

    missing = [f'{title}: {param.name}' for title, param in TABLED if f'| `{param.name}` |' not in section(title)]
    assert not missing, f'missing rows (run .venv/bin/python tools/update_param_tables.py): {missing}'
    assert len(TABLED) > 100


def test_the_example_env_parameters_have_their_table():
    from eqhrl_ros.nodes.double_integrator_env_node import PARAMETERS

    table = README[README.index('#### double_integrator_env') :]
    for name, default, _, _ in PARAMETERS:
        assert f'| `{name}` | `{default}` |' in table, name


def test_message_fields_are_documented():
    for field in (*messages.OBS_TAIL, messages.OBS_SUCCESS, *messages.ACTION_TAIL):
        assert f'`{field}`' in README, field
    # Every field a person's UI may send on teleop_command, in its row of the layouts table (before,
    # take_over was in none: a UI written from the README could not take over).
    row = next(line for line in README.splitlines() if line.startswith('| `teleop_command` | `command`'))
    seal = CommandSeal(Signer(b'a key of this test, 32 bytes long!'))
    full = messages.command_msg([0.0], True, False, False, seal, request=(1, 2), take_over=True)
    for dim in full.layout.dim:
        assert f'`{dim.label}`: {dim.size if dim.label != "command" else "k"}' in row, dim.label


INTERFACES = Path(__file__).resolve().parents[2] / 'eqhrl_interfaces'


@pytest.mark.parametrize('path', sorted(INTERFACES.glob('*/*.msg')) + sorted(INTERFACES.glob('*/*.srv')), ids=str)
def test_every_interface_field_has_a_comment_and_the_readme_links_the_type(path):
    """A field's meaning lives beside it in the .msg/.srv file (one home); the README links there."""
    lines = path.read_text().splitlines()
    for index, line in enumerate(lines):
        text = line.split('#')[0].strip()
        if not text or text == '---' or '=' in text:
            continue  # blank, comment, separator or constant
        # Documented: a comment on its line, or just above it or above its group of fields
        # (consecutive field lines with no blank line between).
        above = index - 1
        while above >= 0 and lines[above].strip() and not lines[above].strip().startswith('#'):
            above -= 1
        documented = '#' in line or (above >= 0 and lines[above].strip().startswith('#'))
        assert documented, f'{path.name}: field without a comment: {line!r}'
    assert f'{path.parent.name}/{path.name}' in README, f'the README does not link {path.name}'


def test_the_readme_states_where_seeds_learn_together():
    """The README's rule for --seeds-together's default is the code's (seed_runs.TOGETHER_MAX_WORK)."""
    import re

    text = (Path(__file__).resolve().parents[1] / 'README.md').read_text()
    width, _, batch = re.search(r'hidden width² × batch size ≤ (\d+) × (\d+) × (\d+)', text).groups()[0:3]
    assert int(width) ** 2 * int(batch) == seed_runs.TOGETHER_MAX_WORK


def test_the_readme_states_how_long_auto_waits_for_the_envs_pace():
    """The README's wait for env_info under advice_protocol auto is the code's (AUTO_PACE_WAIT_S)."""
    from eqhrl_ros.nodes.start_wait import AUTO_PACE_JUDGED_S, AUTO_PACE_WAIT_S

    text = (Path(__file__).resolve().parents[1] / 'README.md').read_text()
    said = f'for at most {AUTO_PACE_WAIT_S:g} s ({AUTO_PACE_JUDGED_S:g} s while an `env_info` that came waits'
    assert said in text


def test_the_results_pages_tables_are_the_committed_reports():
    """docs/results.md's spliced tables equal those of the committed table.md (itself made from the
    committed CSVs by eqhrl-study-report): splicing again changes nothing."""
    import importlib.util

    root = Path(__file__).resolve().parents[2]
    spec = importlib.util.spec_from_file_location('splice', root / 'tools' / 'splice_study_tables.py')
    splice = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(splice)
    page = (root / 'docs' / 'results.md').read_text()
    for study, prefix, markers in (
        ('study_pendulum_decisive', '', ['TESTS', 'ARMS', 'FRONTIER', 'TIMING']),
        ('study_pendulum_takeover', 'TAKEOVER', ['TAKEOVER_TESTS', 'TAKEOVER_PERSON']),
        ('study_pendulum_prior', 'PRIOR', ['PRIOR_TESTS', 'PRIOR_PERSON']),
        ('study_pendulum_prior_controlled', 'PRIORC', ['PRIORC_TESTS', 'PRIORC_PERSON']),
        ('study_lunar_lander_steps', 'LUNARS', ['LUNARS_TESTS', 'LUNARS_ARMS', 'LUNARS_PLACEMENT']),
        ('study_lunar_lander_owed', 'LUNARO', ['LUNARO_TESTS', 'LUNARO_ARMS', 'LUNARO_PLACEMENT']),
        ('study_pendulum_gates', 'GATES', ['GATES_TESTS', 'GATES_ARMS', 'GATES_PLACEMENT', 'GATES_DIFFS']),
        ('study_pendulum_scores', 'SCORES', ['SCORES_TESTS', 'SCORES_ARMS', 'SCORES_PLACEMENT']),
        ('study_pendulum_wheel', 'WHEEL', ['WHEEL_TESTS', 'WHEEL_PERSON']),
        (
            'study_pendulum_imperfect',
            'IMPERFECT',
            ['IMPERFECT_TESTS', 'IMPERFECT_ARMS', 'IMPERFECT_PERSON', 'IMPERFECT_PLACEMENT'],
        ),
    ):
        report = (root / 'docs' / 'results' / study / 'table.md').read_text()
        again, spliced = splice.splice(page, report, prefix)
        assert spliced == markers
        assert again == page, study


def test_the_readmes_camera_example_runs_and_its_memory_figures_are_the_codes():
    """The code block of "Learning from a camera" runs as written, and the bounds its table
    states are what FrameReplay holds."""
    import re

    import numpy as np

    from eqhrl_ros.core.algorithm.config import LearnerConfig
    from eqhrl_ros.core.algorithm.memories import frames_bytes_with_advice
    from eqhrl_ros.core.data.frame_replay import FrameReplay, frame_bytes

    section = README.split('## Learning from a camera', 1)[1].split('\n## ', 1)[0]
    code = re.search(r'```python\n(.*?)```', section, re.S).group(1)
    scope: dict = {}
    exec(compile(code, 'README.md', 'exec'), scope)
    assert scope['learner'].total_steps == 1 and len(scope['learner'].replay) == 1
    assert f'hold {frame_bytes(100_000, (3, 84, 84)) / 1e9:.2f} GB of frames' in section
    advised = FrameReplay(10, (3, 84, 84), 3, 3, 1, isolated=True)
    per_step = advised.frames.nbytes / advised.capacity
    assert per_step == np.prod((3 + 1, 3, 84, 84)) and f'{per_step / 1e3:.1f} kB an advised step' in section
    assert f'frames of D and D_advising: {frames_bytes_with_advice(100_000, (3, 84, 84), 3) / 1e9:.1f} GB' in code
    default = LearnerConfig().replay_capacity
    needed = frames_bytes_with_advice(default, (3, 84, 84), 3) / 1e9
    assert f'{default:,} (Table 1) needs {needed:.1f} GB for 84×84' in section


def test_the_results_pages_pixel_table_is_the_committed_report():
    """docs/results.md's table of learning from pixels is docs/results/pixels/table.md, which
    benchmarks/learn_from_pixels.py --report makes from the committed episodes.csv."""
    root = Path(__file__).resolve().parents[2]
    report = (root / 'docs' / 'results' / 'pixels' / 'table.md').read_text()
    page = (root / 'docs' / 'results.md').read_text()
    assert report in page.split('## Learning from pixels', 1)[1].split('\n## ', 1)[0]
    import csv
    import importlib.util

    spec = importlib.util.spec_from_file_location('learn_from_pixels', root / 'benchmarks' / 'learn_from_pixels.py')
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    with open(root / 'docs' / 'results' / 'pixels' / 'episodes.csv', newline='') as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 2 * 3 * 40  # settings x modes x seeds x episodes
    assert script.table(rows) == report  # made from the committed runs, to the decimal


def test_on_a_ros_install_rosdep_and_the_readmes_pip_line_bring_every_module_the_package_imports():
    """On a ROS install, rosdep installs package.xml's keys, and the root README's pip line installs
    the rest, at the versions requirements.txt pins. Every third-party module the package imports
    comes from one of them (mcap was missing: `record:=true` ended in an ImportError)."""
    import ast
    import importlib.metadata
    import re
    import sys
    import xml.etree.ElementTree as ElementTree

    package = Path(__file__).resolve().parents[1]
    repo = package.parent
    keys = {element.text for element in ElementTree.parse(package / 'package.xml').getroot().iter('exec_depend')}
    readme = (repo / 'README.md').read_text()
    ros_section = readme[readme.index('## With a regular ROS 2 Jazzy install') :]
    pip_line = re.search(r'^pip install (.*?)\n(?!\s)', ros_section, re.S | re.M).group(1)
    pins = dict(re.findall(r'"?([A-Za-z0-9_.\-\[\]]+)==([^\s"\\]+)', pip_line))
    required = dict(re.findall(r'^([A-Za-z0-9_.\-\[\]]+)==(\S+)', (repo / 'requirements.txt').read_text(), re.M))
    assert pins and all(required.get(name) == version for name, version in pins.items()), (pins, required)

    pip_names = {name.split('[')[0].lower() for name in pins}
    optional = set(re.findall(r'needs `pip install ([a-z\-]+)`', (package / 'README.md').read_text()))
    rosdep_dist = {'python3-pil': 'pillow', 'python3-yaml': 'pyyaml'}  # the others: python3-<distribution>
    rosdep_names = {rosdep_dist.get(key, key.removeprefix('python3-')) for key in keys if key.startswith('python3-')}
    distributions = importlib.metadata.packages_distributions()
    modules = set()
    for path in (package / 'eqhrl_ros').rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                modules.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                modules.add(node.module.split('.')[0])
    uncovered = []
    for module in sorted(modules - set(sys.stdlib_module_names) - {'eqhrl_ros'}):
        if module in keys:  # a ROS package: rclpy, std_msgs, launch, eqhrl_interfaces, …
            continue
        names = {name.lower() for name in distributions.get(module, [module])}
        if not names & (pip_names | rosdep_names | optional):
            uncovered.append(f'{module} ({", ".join(sorted(names))})')
    assert not uncovered, f'imported, but neither a rosdep key of package.xml nor in the README pip line: {uncovered}'


def test_the_label_rule_the_message_and_the_readme_state_is_the_cores():
    from eqhrl_ros.core.envs.spec import MAX_LABEL_LENGTH

    rule = f'printable text on one line, at most {MAX_LABEL_LENGTH} characters'
    assert rule in ' '.join((INTERFACES / 'msg' / 'EnvInfo.msg').read_text().replace('#', ' ').split())
    assert rule in README


def test_the_reason_cap_the_service_and_the_readme_state_is_the_learners():
    from eqhrl_ros.nodes.messages import REASON_MAX

    rule = f'one printable line of at most {REASON_MAX} characters'
    assert rule in ' '.join((INTERFACES / 'srv' / 'Advise.srv').read_text().replace('#', ' ').split())
    assert rule in ' '.join(README.split())


def _documented_commands():
    """Each eqhrl-* command in a code block of the READMEs and docs/*.md: (file, program, argv)."""
    import re
    import shlex

    root = Path(__file__).resolve().parents[2]
    for path in [root / 'README.md', root / 'eqhrl_ros' / 'README.md', *sorted((root / 'docs').glob('*.md'))]:
        for block in re.findall(r'```[a-z]*\n(.*?)```', path.read_text(), re.S):
            for line in re.sub(r'\\\n\s*', ' ', block).splitlines():
                found = re.match(r'\s*(?:\.venv/bin/)?(eqhrl-[a-z-]+)\s+(.*)', line)
                if found:
                    words = re.split(r'\s+#', found.group(2))[0]
                    yield path.relative_to(root), found.group(1), shlex.split(words.replace('"$E"', 'E'))


def test_every_documented_eqhrl_command_is_one_its_program_takes(monkeypatch):
    """Each documented command line is parsed by its own program's parser (run no further): a flag
    renamed or a choice dropped in the code, and left in the docs, fails here."""
    import argparse
    import importlib

    class Parsed(Exception):
        pass

    parse = argparse.ArgumentParser.parse_args

    def parse_only(self, args=None, namespace=None):
        raise Parsed(parse(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, 'parse_args', parse_only)
    commands = list(_documented_commands())
    assert len(commands) >= 40
    refused = []
    for path, program, argv in commands:
        main = importlib.import_module(f'eqhrl_ros.cli.{program[len("eqhrl-") :].replace("-", "_")}').main
        try:
            main(argv)
            refused.append(f'{path}: {program} {argv}: ran without parsing its arguments')
        except Parsed:
            pass
        except SystemExit as error:
            refused.append(f'{path}: {program} {" ".join(argv)}: exit {error.code}')
    assert not refused, refused


def _documented_ros2_commands():
    """Each `ros2 run eqhrl_ros …` and `ros2 launch eqhrl_ros …` in the READMEs, docs/*.md and the
    launch files' docstrings, in code blocks and in the text: (file, 'run' or 'launch', target, words)."""
    import re
    import shlex

    root = Path(__file__).resolve().parents[2]
    paths = [root / 'README.md', root / 'eqhrl_ros' / 'README.md', *sorted((root / 'docs').glob('*.md'))]
    for path in [*paths, *sorted((root / 'eqhrl_ros' / 'launch').glob('*.launch.py'))]:
        text = re.sub(r'\\\n\s*', ' ', path.read_text())
        for kind, target, rest in re.findall(r'ros2 (run|launch) eqhrl_ros ([^\s`]+)([^\n`|#(]*)', text):
            if target != '...':
                words = [w for w in shlex.split(rest.replace('...', '')) if w]
                yield path.relative_to(root), kind, target, words


def _run_refusals(node: str, words: list) -> list:
    """What `ros2 run eqhrl_ros <node> <words>` would refuse before it starts: a parameter the node
    does not declare, a value of another type, range or choice, a params file the package lacks."""
    import yaml

    from eqhrl_ros.parameters import check_section

    if node not in NODES:
        return [f'no node {node!r}']
    tables = [params for _, params in node_tables(node)]
    refused, words = [], list(words)
    if words and words[0] != '--ros-args':
        refused.append(f'{words[0]!r} before --ros-args')
    while words:
        word = words.pop(0)
        if word in ('-p', '--params-file', '-r', '--enclave') and words:
            value = words.pop(0)
            if word == '-p':
                name, _, text = value.partition(':=')
                try:
                    check_section(node, {name: yaml.safe_load(text)}, *tables)
                except ValueError as error:
                    if not text.startswith('$'):  # a shell's value ($HOME/…) is a string once expanded
                        refused.append(str(error))
            elif word == '--params-file' and 'params/' in value:
                if not (SHARE / 'params' / Path(value).name).is_file():
                    refused.append(f'no params file {Path(value).name}')
    return refused


def _launch_refusals(launch_file: str, words: list) -> list:
    """What `ros2 launch eqhrl_ros <file> <words>` would not take: an argument the file does not
    declare, an env with no params file, a mode or an expert it does not know."""
    import re

    from eqhrl_ros.core.algorithm.config import MODES

    path = SHARE / 'launch' / launch_file
    if not path.is_file():
        return [f'no launch file {launch_file}']
    text = path.read_text()
    if 'shared_arguments(' in text:
        text += (SHARE / 'eqhrl_ros' / 'nodes' / 'launching.py').read_text()
    declared = set(re.findall(r"DeclareLaunchArgument\(\s*'(\w+)'", text))
    experts = {'train.launch.py': {'expert', 'teleop', 'none'}, 'actors.launch.py': {'true', 'false'}}
    choices = {'mode': set(MODES), 'expert': experts[launch_file]}
    refused = []
    for word in words:
        name, _, value = word.partition(':=')
        if name not in declared:
            refused.append(f'{name!r} is no argument of {launch_file} ({", ".join(sorted(declared))})')
        elif name == 'env' and not (SHARE / 'params' / f'{value}.yaml').is_file():
            refused.append(f'env:={value}: no params/{value}.yaml')
        elif name in choices and value not in choices[name]:
            refused.append(f'{name}:={value} is not one of {sorted(choices[name])}')
    return refused


SHARE = Path(__file__).resolve().parents[1]  # eqhrl_ros/: params/, launch/, the code


def test_every_documented_ros2_command_names_what_its_node_or_launch_file_takes():
    """From outside, every documented command must work as written: a parameter renamed in the code,
    a params file or a launch argument dropped, and left in the docs, fails here."""
    commands = list(_documented_ros2_commands())
    assert len([c for c in commands if c[1] == 'run']) >= 40 and len([c for c in commands if c[1] == 'launch']) >= 15
    refused = []
    for path, kind, target, words in commands:
        found = _run_refusals(target, words) if kind == 'run' else _launch_refusals(target, words)
        refused += [f'{path}: ros2 {kind} eqhrl_ros {target} {" ".join(words)}: {why}' for why in found]
    assert not refused, '\n'.join(refused)
