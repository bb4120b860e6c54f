"""Where the installed package keeps its params and launch files."""

from __future__ import annotations

import sys
from pathlib import Path


def share_dir() -> Path:
    """share/eqhrl_ros of the install (ament index first; the venv prefix as a fallback)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory('eqhrl_ros'))
    except Exception:  # no ament index on the path (e.g. AMENT_PREFIX_PATH unset in a venv)
        return Path(sys.prefix) / 'share' / 'eqhrl_ros'


def params_file(name_or_path: str) -> Path:
    """A params file by path, or by short name (``pendulum`` -> share/eqhrl_ros/params/pendulum.yaml)."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml') and path.exists():
        return path
    candidate = share_dir() / 'params' / f'{path.stem}.yaml'
    if candidate.exists():
        return candidate
    available = sorted(p.stem for p in (share_dir() / 'params').glob('*.yaml'))
    raise FileNotFoundError(f'no params file {name_or_path!r}; give a path or one of {available}')
