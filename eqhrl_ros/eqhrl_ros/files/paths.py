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


def shared_file(folder: str, name_or_path: str, what: str) -> Path:
    """A YAML file by path, or by short name from share/eqhrl_ros/<folder>
    (``pendulum`` -> share/eqhrl_ros/<folder>/pendulum.yaml); ``what`` names it in the error."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml') and path.exists():
        return path
    candidate = share_dir() / folder / f'{path.stem}.yaml'
    if candidate.exists():
        return candidate
    available = sorted(p.stem for p in (share_dir() / folder).glob('*.yaml'))
    raise FileNotFoundError(f'no {what} {name_or_path!r}; give a path or one of {available}')


def params_file(name_or_path: str) -> Path:
    """A params file by path, or by short name (``pendulum`` -> share/eqhrl_ros/params/pendulum.yaml)."""
    return shared_file('params', name_or_path, 'params file')
