"""A tiny TOML writer (tomllib only reads): scenes' emitted text and generated test files.

:func:`dumps_toml` writes plain values (str, int, float, bool, lists, dicts) so that
``tomllib.loads`` gives them back; the scene stores this text in every output file
when it was not read from one (:meth:`sphgraph.scene.Scene.from_dict`).
"""
from __future__ import annotations

import json
import math
import re

import numpy as np

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else _toml_str(k)


def _toml_str(s: str) -> str:
    # JSON string escapes are a subset of TOML basic-string escapes; DEL must be escaped too
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_value(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)  # shortest round-trip form; '1e-05' is valid TOML
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}"
                               for k, x in v.items() if x is not None) + "}"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _is_table_array(v) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, dict) for x in v)


def _emit(table: dict, path: list, lines: list) -> None:
    for k, v in table.items():  # plain key/values first: they belong to this table's header
        if v is not None and not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        p = path + [_toml_key(k)]
        if isinstance(v, dict):
            lines += ["", f"[{'.'.join(p)}]"]
            _emit(v, p, lines)
        elif _is_table_array(v):
            for item in v:
                lines += ["", f"[[{'.'.join(p)}]]"]
                _emit(item, p, lines)


def dumps_toml(d: dict) -> str:
    """TOML text for a dict of plain values (str, int, float, bool, lists, dicts).

    ``None`` values are left out (TOML has no null). ``tomllib.loads`` of the
    result equals ``d`` up to those omissions and tuples read back as lists.
    """
    lines: list = []
    _emit(d, [], lines)
    return "\n".join(lines).lstrip("\n") + "\n"
