"""JSON a user can hand cnep, read with a size and a nesting limit (a hostile file costs bounded time and memory).

    data = read_json(path)                  # ValueError for too large, too deep, not UTF-8 or not JSON
    data = parse_json(text, what="a line")  # the same checks on text already in memory

Python's `json` recurses once per nesting level, so a few thousand `[` end in RecursionError; here the depth is
counted first, without recursion, and anything deeper than MAX_DEPTH is refused. Every error is a `ValueError`
(as `json.JSONDecodeError` and `UnicodeDecodeError` are), whose text says what is wrong; callers add the file and
the fix. Used by the runtime (an exported policy's manifest) and by the libraries' and the pipeline's readers
alike; it lives in the runtime because the runtime imports no other part of cnep.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

MAX_BYTES = 16 << 20  # the largest JSON document read (bytes); cnep's own are far smaller
MAX_DEPTH = 64  # the deepest nesting of arrays and objects read; cnep's own files nest under ten levels

_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)  # a JSON string literal (brackets inside it do not nest)
_STEP = np.zeros(256, np.int8)  # byte -> change of depth: +1 for [ and {, -1 for ] and }, 0 for any other
_STEP[[ord("["), ord("{")]], _STEP[[ord("]"), ord("}")]] = 1, -1


def nesting_depth(text: str) -> int:
    """The deepest nesting of arrays and objects in JSON `text` (0 for a scalar), counted without recursion."""
    if text.count("[") + text.count("{") <= 1:
        return int("[" in text or "{" in text)
    steps = _STEP[np.frombuffer(_STRING.sub("", text).encode("utf-8", "replace"), np.uint8)]  # (n,) bytes' steps
    return int(np.cumsum(steps, dtype=np.int64).max(initial=0))


def parse_json(text: str | bytes, *, max_bytes: int = MAX_BYTES, max_depth: int = MAX_DEPTH) -> object:
    """The JSON value of `text`; ValueError if it is larger than `max_bytes`, nests deeper than `max_depth`, is not
    UTF-8 (bytes) or is not JSON."""
    if len(text) > max_bytes:
        raise ValueError(f"larger than the {max_bytes} bytes a JSON file may hold")
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    depth = nesting_depth(text)
    if depth > max_depth:
        raise ValueError(f"nested {depth} levels deep, deeper than the {max_depth} a JSON file may be")
    return json.loads(text)


def read_json(path: str | Path, *, max_bytes: int = MAX_BYTES, max_depth: int = MAX_DEPTH) -> object:
    """The JSON value of the file at `path` (at most `max_bytes` of it are read); OSError if it cannot be read,
    ValueError as `parse_json`."""
    with open(path, "rb") as f:
        data = f.read(max_bytes + 1)
    return parse_json(data, max_bytes=max_bytes, max_depth=max_depth)
