"""Every YAML file this package reads (params files, study plans, a run's settings), read one way.

A file is refused with one line naming it and the problem (YamlFileError, a ValueError), before
anything is built from it, when it is
- larger than ``max_bytes`` (a params file or a plan is a few KB; 1 MiB by default),
- not UTF-8 text,
- nested deeper than ``MAX_DEPTH`` mappings and lists,
- using anchors and aliases (a "billion laughs" file expands a few lines into gigabytes; no
  params file or plan needs them, and rcl's own params parser does not read them),
- anything the safe loader refuses (tags such as ``!!python/object``, bad syntax), or
- not a mapping at its top (a file whose whole content is ``42`` or a list).

One tag beyond the safe loader's is read: ``!!python/tuple``, as a list. launch_ros writes a
node's parameters to a temporary params file with ``yaml.dump``, which tags every tuple so
(``hidden_sizes``, ``actors``), and builds nothing from it but a sequence of plain values.

The events are checked first, by the parser alone (no objects are built, no recursion), so a
deep or huge file costs time in proportion to its size up to the limits, and no more.
"""

from __future__ import annotations

from pathlib import Path

import yaml

MAX_BYTES = 1 << 20
MAX_DEPTH = 32
_SAFE = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)  # libyaml where PyYAML has it
TUPLE_TAG = 'tag:yaml.org,2002:python/tuple'


class _Loader(_SAFE):
    """The safe loader, and launch_ros's tuples as lists (nothing else of Python's tags)."""


_Loader.add_constructor(TUPLE_TAG, lambda loader, node: loader.construct_sequence(node, deep=True))
_LOADER = _Loader


class YamlFileError(ValueError):
    """A YAML file refused: the message names the file and the problem, in one line."""


def load_mapping(path, what: str = 'YAML file', max_bytes: int = MAX_BYTES) -> dict:
    """The top-level mapping of the YAML file at ``path`` (an empty file: {}), or YamlFileError."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise YamlFileError(f'{what} {path}: {size:,} bytes; at most {max_bytes:,} are read')
        data = path.read_bytes()[: max_bytes + 1]
    except OSError as error:
        raise YamlFileError(f'{what} {path}: cannot be read ({error.strerror or error})') from None
    return loads_mapping(data, f'{what} {path}', max_bytes)


def loads_mapping(data: bytes | str, where: str = 'YAML text', max_bytes: int = MAX_BYTES) -> dict:
    """The top-level mapping of YAML ``data`` (bytes or text), checked as load_mapping checks a file."""
    if isinstance(data, str):
        data = data.encode('utf-8')
    if len(data) > max_bytes:
        raise YamlFileError(f'{where}: {len(data):,} bytes; at most {max_bytes:,} are read')
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as error:
        raise YamlFileError(f'{where}: not UTF-8 text (byte {error.start})') from None
    try:
        depth = 0
        for event in yaml.parse(text, Loader=_LOADER):
            if isinstance(event, yaml.AliasEvent) or getattr(event, 'anchor', None):
                raise YamlFileError(f'{where}: anchors and aliases (&, *) are not accepted{_at(event)}')
            if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                depth += 1
                if depth > MAX_DEPTH:
                    raise YamlFileError(f'{where}: nested deeper than {MAX_DEPTH} levels{_at(event)}')
            elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                depth -= 1
        loaded = yaml.load(text, Loader=_LOADER)
    except yaml.YAMLError as error:
        raise YamlFileError(f'{where}: {_one_line(error)}') from None
    if loaded is None:
        return {}
    if not isinstance(loaded, dict):
        raise YamlFileError(f'{where}: expected a mapping (key: value lines) at the top, got {type(loaded).__name__}')
    return loaded


def _at(event) -> str:
    mark = getattr(event, 'start_mark', None)
    return f' (line {mark.line + 1})' if mark is not None else ''


def _one_line(error: yaml.YAMLError) -> str:
    problem = getattr(error, 'problem', None) or str(error).split('\n')[0]
    mark = getattr(error, 'problem_mark', None)
    context = getattr(error, 'context', None)
    text = f'{context}: {problem}' if context and problem != context else problem
    return ' '.join(f'{text}{f" (line {mark.line + 1})" if mark is not None else ""}'.split())
