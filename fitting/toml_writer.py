"""Writing TOML: ``dumps(doc)`` for the subset experiment files use, and ``write_atomic``.

Python reads TOML (``tomllib``) but does not write it; this emitter covers what
``fitting.data`` reads back: strings, floats (``repr``: the shortest text that reads back as
the same double; ``inf``, ``nan``), integers, booleans, arrays, tables and arrays of tables.
``tomllib.loads(dumps(doc)) == doc`` for any such document (tests/test_toml_writer.py).

Layout: in every table its plain keys first (arrays, and tables without nested tables
written inline as ``{ k = v }``), then its sub-tables as ``[a.b]`` sections and its arrays of
tables as ``[[a.b]]``, in the document's order; the top-level tables are always sections.
``comments`` maps a key path (a tuple of keys and array indices, e.g. ``("material",
"units", 0, "eta")``) to a comment written at the end of that key's line or section header.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Mapping

from dejax.results import atomic_file

__all__ = ["dumps", "write_atomic"]

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def _string(s: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = []
    for ch in s:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _key(k) -> str:
    if not isinstance(k, str):
        raise TypeError(f"TOML keys must be strings, got {k!r}")
    return k if _BARE_KEY.match(k) else _string(k)


def _float(x: float) -> str:
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)  # always has '.' or 'e': read back as a float, the same double


def _dotted(path: tuple) -> str:
    return ".".join(_key(k) for k in path if isinstance(k, str))


def _where(path: tuple) -> str:
    return ".".join(str(k) for k in path) or "(top level)"


def _value(v, path: tuple) -> str:
    """The inline TOML text of a value."""
    if isinstance(v, bool):  # before int: bool is an int
        return "true" if v else "false"
    if isinstance(v, int):
        return str(int(v))
    if isinstance(v, float):
        return _float(float(v))
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x, path + (i,)) for i, x in enumerate(v)) + "]"
    if isinstance(v, Mapping):
        if not v:
            return "{}"
        return "{ " + ", ".join(f"{_key(k)} = {_value(x, path + (k,))}" for k, x in v.items()) + " }"
    item = getattr(v, "item", None)  # numpy scalars
    if callable(item) and getattr(v, "ndim", None) == 0:
        return _value(item(), path)
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML (at {_where(path)})")


def _is_table_array(v) -> bool:
    return isinstance(v, (list, tuple)) and len(v) > 0 and all(isinstance(x, Mapping) for x in v)


def _is_section(v, path: tuple) -> bool:
    """Whether the table ``v`` at ``path`` is written as a [section]: at the top level, or
    when it holds tables itself; otherwise inline."""
    if not isinstance(v, Mapping):
        return False
    nested = any(isinstance(x, Mapping) or _is_table_array(x) for x in v.values())
    return len(path) == 1 or nested


def _comment(comments, path) -> str:
    text = comments.get(path)
    return "" if not text else "  # " + " ".join(str(text).split())


def _body(table: Mapping, path: tuple, comments, lines: list) -> None:
    """Append the lines of ``table`` (at key path ``path``): its plain keys, then its
    sections and arrays of tables."""
    headers = []
    for k, v in table.items():
        sub = path + (k,)
        if _is_table_array(v):
            headers.append((k, v))
        elif _is_section(v, sub):
            headers.append((k, v))
        else:
            lines.append(f"{_key(k)} = {_value(v, sub)}{_comment(comments, sub)}")
    for k, v in headers:
        sub = path + (k,)
        if isinstance(v, Mapping):
            lines += ["", f"[{_dotted(sub)}]{_comment(comments, sub)}"]
            _body(v, sub, comments, lines)
        else:
            for i, element in enumerate(v):
                lines += ["", f"[[{_dotted(sub)}]]{_comment(comments, sub + (i,))}"]
                _body(element, sub + (i,), comments, lines)


def dumps(doc: Mapping[str, Any], comments: Mapping[tuple, str] | None = None, header: str = "") -> str:
    """The TOML text of ``doc`` (see the module docstring); ``header``: comment lines on top."""
    if not isinstance(doc, Mapping):
        raise TypeError(f"a TOML document is a table, got {type(doc).__name__}")
    lines = [("# " + line).rstrip() for line in header.splitlines()]
    _body(doc, (), dict(comments or {}), lines)
    while lines and not lines[0]:
        lines.pop(0)
    return "\n".join(lines) + "\n"


def write_atomic(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through a temporary file in the same folder renamed
    at the end: a failure never leaves a half-written file. Returns the path."""
    p = Path(path)
    with atomic_file(p) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
    return p
