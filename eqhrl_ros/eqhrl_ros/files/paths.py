"""Where the installed package keeps its params and launch files."""

from __future__ import annotations

import sys
from pathlib import Path


def share_dir(package: str = 'eqhrl_ros') -> Path:
    """share/<package> of the install (ament index first; the venv prefix as a fallback)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(package))
    except Exception:  # no ament index on the path (e.g. AMENT_PREFIX_PATH unset in a venv)
        return Path(sys.prefix) / 'share' / package


def shipped(folder: str) -> list[str]:
    """The short names of the YAML files shipped in share/eqhrl_ros/<folder> (``params``, ``studies``)."""
    return sorted(p.stem for p in (share_dir() / folder).glob('*.yaml'))


def shared_file(folder: str, name_or_path: str, what: str) -> Path:
    """A YAML file by path, or by short name from share/eqhrl_ros/<folder>
    (``pendulum`` -> share/eqhrl_ros/<folder>/pendulum.yaml); ``what`` names it in the error.
    A path (a folder in it, or a suffix) is only ever that file: a mistyped path to a user's own
    ``pendulum.yaml`` used to fall back to the shipped one, silently."""
    path = Path(name_or_path)
    available = shipped(folder)
    if path.name != name_or_path or path.suffix:  # a path: that file, never a shipped one of its name
        if not path.is_file():
            raise FileNotFoundError(f'no {what} {name_or_path!r}: no such file (or give one of {available})')
        if path.suffix not in ('.yaml', '.yml'):
            raise FileNotFoundError(f'{name_or_path!r} is not a {what}: give a .yaml file (or one of {available})')
        return path
    candidate = share_dir() / folder / f'{name_or_path}.yaml'
    if candidate.exists():
        return candidate
    raise FileNotFoundError(f'no {what} {name_or_path!r}; give a path or one of {available}')


def params_file(name_or_path: str) -> Path:
    """A params file by path, or by short name (``pendulum`` -> share/eqhrl_ros/params/pendulum.yaml)."""
    return shared_file('params', name_or_path, 'params file')
