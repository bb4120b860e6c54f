"""Every run folder says what made each start of its run (core/runs/provenance.py)."""

import re
import subprocess
from importlib import metadata
from pathlib import Path

import yaml

from eqhrl_ros.core.runs.provenance import git_state, note_provenance, provenance
from eqhrl_ros.core.runs.records import RunFolder

REPO = Path(__file__).resolve().parents[4]


def test_each_start_adds_its_commit_version_and_whether_the_tree_was_dirty(tmp_path):
    RunFolder(tmp_path / 'run').begin()
    RunFolder(tmp_path / 'run', resume=False, overwrite=True)  # refused later (a prior of another env): no entry
    RunFolder(tmp_path / 'run', resume=False, overwrite=True).begin()  # a second start of the same folder
    starts = yaml.safe_load((tmp_path / 'run' / 'provenance.yaml').read_text())['starts']
    assert len(starts) == 2
    entry = starts[0]
    assert entry['package_version'] == metadata.version('eqhrl_ros')
    assert entry['dirty'] in (True, False, 'unknown')
    assert entry['commit'] == 'unknown' or re.fullmatch('[0-9a-f]{40}', entry['commit'])
    if entry['commit'] != 'unknown' and (REPO / '.git').exists():  # a commit of this repository
        subprocess.run(['git', '-C', str(REPO), 'cat-file', '-e', f'{entry["commit"]}^{{commit}}'], check=True)


def test_a_checkout_says_its_head_and_whether_a_tracked_file_changed(tmp_path):
    def git(*args):
        subprocess.run(['git', '-C', str(tmp_path), *args], check=True, capture_output=True)

    git('init', '-q')
    (tmp_path / 'a.txt').write_text('1\n')
    git('add', 'a.txt')
    git('-c', 'user.name=t', '-c', 'user.email=t@t', 'commit', '-q', '-m', 'one')
    head = subprocess.run(['git', '-C', str(tmp_path), 'rev-parse', 'HEAD'], capture_output=True, text=True).stdout
    assert git_state(tmp_path) == {'commit': head.strip(), 'dirty': False}
    (tmp_path / 'untracked.txt').write_text('not part of the tree\n')
    assert git_state(tmp_path)['dirty'] is False
    (tmp_path / 'a.txt').write_text('2\n')
    assert git_state(tmp_path)['dirty'] is True
    assert git_state(tmp_path / 'missing') == {}


def test_an_unreadable_note_is_kept_aside_and_a_full_disk_costs_the_note_not_the_run(tmp_path, monkeypatch):
    (tmp_path / 'provenance.yaml').write_text('starts: [unclosed\n')
    assert note_provenance(tmp_path) == tmp_path / 'provenance.yaml'
    assert (tmp_path / 'provenance.yaml.unreadable').read_text() == 'starts: [unclosed\n'
    assert len(yaml.safe_load((tmp_path / 'provenance.yaml').read_text())['starts']) == 1

    def full(self, *args, **kwargs):
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(Path, 'write_text', full)
    assert note_provenance(tmp_path) is None
    assert not list(tmp_path.glob('.provenance.yaml.tmp'))
    assert provenance()['python']
