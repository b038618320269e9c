"""What passes between the grader and the student's process: messages of JSON and raw arrays, never
pickle (unpickling what the student's process sends would run its code in the grader).

A message is MAGIC, the length of a JSON header, the header (`meta`, any JSON, and each array's name,
dtype and shape), then the arrays' bytes back to back. `decode` checks the whole message before it
makes an array: the magic, the header's size and form, each dtype from a short list, each shape, and
that the bytes are exactly as many as the header says; the arrays are read-only views of the
message (np.frombuffer: nothing is allocated beyond what came). Anything else is a WireError.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

MAGIC = b"MZL1"
MAX_HEADER_BYTES = 1 << 20
MAX_MESSAGE_BYTES = 1 << 28  # 256 MB: the largest message a child may send (the grader reads no more)
DTYPES = ("<f8", "<i8", "|b1")  # float64, int64, bool: all the checks exchange


class WireError(ValueError):
    """A message that is not one of ours: what is wrong with it, in one line."""


@dataclass
class Message:
    """A decoded message: its JSON `meta` and its arrays by name."""

    meta: dict[str, Any]
    arrays: dict[str, np.ndarray] = field(default_factory=dict)


def _wire_array(array: np.ndarray) -> np.ndarray:
    """The array in one of DTYPES, little-endian, contiguous."""
    array = np.asarray(array)
    if array.dtype == bool:
        kind = "|b1"
    elif np.issubdtype(array.dtype, np.integer):
        kind = "<i8"
    else:
        kind = "<f8"
    return np.ascontiguousarray(array, dtype=np.dtype(kind))


def encode(meta: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> bytes:
    """One message: `meta` (JSON; finite floats only) and the arrays (as float64, int64 or bool)."""
    wired = {name: _wire_array(value) for name, value in (arrays or {}).items()}
    header = {
        "meta": meta,
        "arrays": [{"name": name, "dtype": a.dtype.str, "shape": list(a.shape)} for name, a in wired.items()],
    }
    text = json.dumps(header, allow_nan=False, separators=(",", ":")).encode()
    return b"".join([MAGIC, len(text).to_bytes(4, "big"), text, *(a.tobytes() for a in wired.values())])


def decode(data: bytes) -> Message:
    """The message in `data`, checked whole (see the module docstring); WireError otherwise."""
    if len(data) > MAX_MESSAGE_BYTES:
        raise WireError(f"a message of {len(data)} bytes (at most {MAX_MESSAGE_BYTES})")
    if data[:4] != MAGIC or len(data) < 8:
        raise WireError("not a message of the grader's (no header)")
    size = int.from_bytes(data[4:8], "big")
    if size > MAX_HEADER_BYTES or 8 + size > len(data):
        raise WireError(f"a header of {size} bytes")
    try:
        header = json.loads(data[8 : 8 + size], parse_constant=_no_constant)
    except (ValueError, RecursionError) as error:
        raise WireError(f"a header that is not JSON ({error})") from None
    if not isinstance(header, dict) or set(header) != {"meta", "arrays"} or not isinstance(header["meta"], dict):
        raise WireError("a header without meta and arrays")
    if not isinstance(header["arrays"], list):
        raise WireError("a header whose arrays are not a list")
    arrays, offset = {}, 8 + size
    for entry in header["arrays"]:
        name, dtype, shape = _array_entry(entry)
        if name in arrays:
            raise WireError(f"the array {name!r} twice")
        nbytes = math.prod(shape) * dtype.itemsize
        if offset + nbytes > len(data):
            raise WireError(f"the array {name!r} is cut short")
        arrays[name] = np.frombuffer(data, dtype=dtype, count=math.prod(shape), offset=offset).reshape(shape)
        offset += nbytes
    if offset != len(data):
        raise WireError(f"{len(data) - offset} bytes after the last array")
    return Message(header["meta"], arrays)


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not JSON")


def _array_entry(entry: Any) -> tuple[str, np.dtype, tuple[int, ...]]:
    """(name, dtype, shape) of a header's array entry, checked."""
    if not isinstance(entry, dict) or set(entry) != {"name", "dtype", "shape"}:
        raise WireError("an array entry without name, dtype and shape")
    name, dtype, shape = entry["name"], entry["dtype"], entry["shape"]
    if not isinstance(name, str) or len(name) > 200:
        raise WireError("an array whose name is not a short text")
    if dtype not in DTYPES:
        raise WireError(f"the array {name!r} has dtype {dtype!r} (one of {', '.join(DTYPES)} expected)")
    if (
        not isinstance(shape, list)
        or len(shape) > 4
        or not all(isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= MAX_MESSAGE_BYTES for n in shape)
    ):
        raise WireError(f"the array {name!r} has shape {shape!r}")
    return name, np.dtype(dtype), tuple(shape)


__all__ = ["DTYPES", "MAGIC", "MAX_MESSAGE_BYTES", "Message", "WireError", "decode", "encode"]
