"""Hostile YAML files (plans, params files) are refused in one line, small and fast, by every reader."""

import subprocess
import sys
from pathlib import Path

import pytest

from eqhrl_ros.files.yaml_files import MAX_DEPTH, YamlFileError, load_mapping

BIN = Path(sys.executable).parent


def _laughs() -> str:
    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(8):
        prev, name = chr(97 + i), chr(98 + i)
        lines.append(f'{name}: &{name} [{", ".join([f"*{prev}"] * 9)}]')
    return '\n'.join(lines) + '\n'


HOSTILE = {
    'billion_laughs': (_laughs(), 'anchors and aliases'),
    'deep_lists': ('a: ' + '[' * 100_000 + ']' * 100_000 + '\n', f'nested deeper than {MAX_DEPTH}'),
    'deep_mappings': (''.join(' ' * i + f'k{i}:\n' for i in range(200)), f'nested deeper than {MAX_DEPTH}'),
    'python_tag': ('a: !!python/object/apply:os.system ["echo ran"]\n', 'could not determine a constructor'),
    'number': ('42\n', 'expected a mapping'),
    'list': ('- a\n- b\n', 'expected a mapping'),
    'syntax': ('a: [1, 2\nb: 3\n', "did not find expected ','"),
}


def write(tmp_path, name, text) -> Path:
    path = tmp_path / f'{name}.yaml'
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


@pytest.mark.parametrize('name', sorted(HOSTILE))
def test_a_hostile_file_is_refused_with_one_line_naming_it(tmp_path, name):
    text, problem = HOSTILE[name]
    path = write(tmp_path, name, text)
    with pytest.raises(YamlFileError) as refused:
        load_mapping(path, 'study plan')
    message = str(refused.value)
    assert message.startswith(f'study plan {path}: ') and problem in message and '\n' not in message


def test_invalid_utf8_and_an_oversized_file_are_refused_before_parsing(tmp_path):
    with pytest.raises(YamlFileError, match=r'not UTF-8 text \(byte 3\)'):
        load_mapping(write(tmp_path, 'utf8', b'a: \xff\xfe\n'))
    big = tmp_path / 'big.yaml'
    with big.open('wb') as f:
        f.truncate(100 * 1024 * 1024)  # 100 MB, sparse: nothing of it needs reading to refuse it
    with pytest.raises(YamlFileError, match='104,857,600 bytes; at most 1,048,576'):
        load_mapping(big)


def test_launch_ros_params_files_with_python_tuples_load_as_lists(tmp_path):
    # What launch_ros writes for Node(parameters=[{...}]): yaml.dump of a dict whose lists it made tuples.
    import yaml

    dumped = yaml.dump({'/**': {'ros__parameters': {'hidden_sizes': (64, 64), 'actors': ('/a/actor',)}}})
    assert '!!python/tuple' in dumped
    loaded = load_mapping(write(tmp_path, 'launch_params', dumped), 'params file')
    assert loaded['/**']['ros__parameters'] == {'hidden_sizes': [64, 64], 'actors': ['/a/actor']}
    # Any other Python tag is still refused, inside a tuple too.
    with pytest.raises(YamlFileError, match='could not determine a constructor'):
        load_mapping(write(tmp_path, 'inner', 'a: !!python/tuple [!!python/name:os.system ""]\n'))


def test_a_good_file_loads_and_an_empty_one_is_an_empty_mapping(tmp_path):
    assert load_mapping(write(tmp_path, 'ok', 'a: 1\nb: [1, {c: x}]\n')) == {'a': 1, 'b': [1, {'c': 'x'}]}
    assert load_mapping(write(tmp_path, 'empty', '')) == {}


def test_the_worst_files_cost_little_memory(tmp_path):
    """A child process reads each, alone: its peak resident memory (VmHWM, of its own address
    space, not the forking parent's) stays under 100 MB."""
    paths = [write(tmp_path, name, HOSTILE[name][0]) for name in ('billion_laughs', 'deep_lists')]
    probe = (
        'import sys\nfrom eqhrl_ros.files.yaml_files import load_mapping\n'
        'try:\n    load_mapping(sys.argv[1])\nexcept ValueError:\n    pass\nelse:\n    sys.exit(3)\n'
        "print([l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1])\n"
    )
    for path in paths:
        done = subprocess.run([sys.executable, '-c', probe, str(path)], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        assert int(done.stdout) < 100 * 1024, f'{path.name}: {done.stdout} KB'


@pytest.mark.slow
@pytest.mark.parametrize(
    'command',
    [
        ['eqhrl-study', '--output', 'OUT', '--list', '--plan'],
        ['eqhrl-experiment', '--output', 'OUT', '--params'],
        ['learner', '--ros-args', '--params-file'],
    ],
    ids=['eqhrl-study', 'eqhrl-experiment', 'learner'],
)
def test_the_commands_refuse_hostile_files_with_one_line_and_exit_2(tmp_path, command):
    for name in ('billion_laughs', 'deep_lists', 'python_tag', 'number'):
        path = write(tmp_path, name, HOSTILE[name][0])
        args = [str(BIN / command[0]), *[str(tmp_path / 'out') if a == 'OUT' else a for a in command[1:]], str(path)]
        done = subprocess.run(args, capture_output=True, text=True, timeout=60)
        assert done.returncode == 2, (name, done.stderr)
        assert done.stderr.count('\n') == 1 and str(path) in done.stderr and 'Traceback' not in done.stderr, done.stderr
        assert not (tmp_path / 'out').exists()


def test_a_params_path_is_that_file_and_never_a_shipped_one_of_its_name(tmp_path, monkeypatch):
    """Before: `--params runs/mine/pendulum.yaml`, mistyped, silently ran the shipped pendulum.yaml
    (its stem was looked up among the shipped files), and `--params /etc/passwd` said 'no params file'."""
    from eqhrl_ros.files.paths import params_file, share_dir

    monkeypatch.chdir(tmp_path)
    assert params_file('pendulum') == share_dir() / 'params' / 'pendulum.yaml'  # a short name
    with pytest.raises(FileNotFoundError, match="no params file 'runs/mine/pendulum.yaml': no such file"):
        params_file('runs/mine/pendulum.yaml')
    with pytest.raises(FileNotFoundError, match="no params file 'pendulum.yaml': no such file"):
        params_file('pendulum.yaml')  # a file name is a path too (here, in the working folder)
    (tmp_path / 'notes.txt').write_text('learner: {}\n')
    with pytest.raises(FileNotFoundError, match="'notes.txt' is not a params file: give a .yaml file"):
        params_file('notes.txt')
    (tmp_path / 'pendulum.yaml').write_text('learner: {}\n')
    assert params_file('pendulum.yaml') == Path('pendulum.yaml')  # one's own, beside the shipped one
