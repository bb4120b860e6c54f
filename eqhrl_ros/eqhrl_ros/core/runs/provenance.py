"""What made a run: the package's version, the commit its source came from and whether that
tree had changes not committed, written into every run folder (provenance.yaml).

The commit is found when the package is built (setup.py writes it into the package as
build_info.json: pip, make setup and colcon build all run setup.py), or, for a package read
straight from a git checkout (PYTHONPATH), from that checkout. A package built from a tree that
is not a git checkout says so ('unknown'). Each start of a run (fresh or resumed) adds one entry,
so a run continued by other code says that too.
"""

from __future__ import annotations

import datetime
import json
import platform
import subprocess
from importlib import metadata, resources
from pathlib import Path
from typing import Optional

BUILD_INFO = 'build_info.json'  # in the installed package, beside its __init__.py
PROVENANCE_FILE = 'provenance.yaml'


def git_state(tree: Path) -> dict:
    """{'commit': the checkout's HEAD, 'dirty': tracked files changed since} of the git checkout at
    ``tree``; {} where it is not one (or git is missing)."""
    def git(*args) -> str:
        return subprocess.run(
            ['git', '-C', str(tree), *args], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()

    try:
        commit = git('rev-parse', 'HEAD')
        dirty = bool(git('status', '--porcelain', '--untracked-files=no'))
    except (OSError, subprocess.SubprocessError):
        return {}
    return {'commit': commit, 'dirty': dirty}


def build_state() -> dict:
    """The commit the installed package was built from (build_info.json), else that of the
    checkout the package is read from, else {}."""
    try:
        return json.loads(resources.files('eqhrl_ros').joinpath(BUILD_INFO).read_text())
    except (OSError, ValueError):
        pass
    package = Path(__file__).resolve().parents[2]  # eqhrl_ros/eqhrl_ros
    return git_state(package) if (package.parent / 'setup.py').exists() else {}


def provenance() -> dict:
    """This process's entry: when, the package version, the commit and whether it was dirty."""
    try:
        version = metadata.version('eqhrl_ros')
    except metadata.PackageNotFoundError:
        version = 'unknown'
    state = build_state()
    import torch

    return {
        'started': datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
        'package_version': version,
        'commit': state.get('commit', 'unknown'),
        'dirty': state.get('dirty', 'unknown'),
        'python': platform.python_version(),
        'torch': str(torch.__version__),
    }


def note_provenance(folder, about: Optional[dict] = None) -> Optional[Path]:
    """Add this start's entry to ``folder``/provenance.yaml (made if absent), with ``about`` (what
    the run is: env, mode, seed) after it; returns its path.
    A file that cannot be read is kept aside as provenance.yaml.unreadable, never lost. A note
    that cannot be written (a full disk) costs the note, not the run: None."""
    import yaml  # here, not above: setup.py reads git_state() from this file while building

    path = Path(folder) / PROVENANCE_FILE
    entries = []
    if path.exists():
        try:
            loaded = yaml.safe_load(path.read_text())
            entries = list(loaded.get('starts', [])) if isinstance(loaded, dict) else []
        except (OSError, yaml.YAMLError):
            path.replace(path.with_name(PROVENANCE_FILE + '.unreadable'))
    entries.append({**provenance(), **(about or {})})
    tmp = path.with_name(f'.{PROVENANCE_FILE}.tmp')
    try:
        tmp.write_text(yaml.safe_dump({'starts': entries}, sort_keys=False))
        tmp.replace(path)
    except OSError:
        tmp.unlink(missing_ok=True)
        return None
    return path
