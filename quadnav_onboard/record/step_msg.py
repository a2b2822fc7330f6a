"""The step channel's message, ``quadnav.Step``: the core's typed step record, protobuf encoded.

Its fields are :class:`quadnav_onboard.step.StepRecord`'s, declared there once: the schema (a
protobuf ``FileDescriptorSet``, what Foxglove and :mod:`decode` read) is generated from the
dataclass's fields, in their order, after ``t_mono_s`` (the decision's ``time.monotonic()``, s)
and before the recorder's own ``latency_ms`` (depth capture to setpoint sent, ms; NaN: not
measured). A field's protobuf type follows its dtype (float -> ``double``, int -> ``int32``, bool ->
``bool``); a field with one value per vehicle (:data:`ROW_SCALARS`) is a single value, the others
(vectors, one value per primitive) are packed ``repeated`` fields. A field that is None (the depth
safety filter off) is left out, and reads back as an empty list.

Encoding writes protobuf's wire format directly (fixed key bytes computed once, arrays as raw
little-endian bytes), so a step costs a few microseconds of the writer's time.
"""

from __future__ import annotations

import dataclasses
import math
import re
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np

from quadnav_onboard.step import StepRecord

__all__ = [
    "FIELDS",
    "ROW_SCALARS",
    "SCHEMA_NAME",
    "StepField",
    "descriptor_set",
    "encode",
    "encode_record",
    "row_of_kwargs",
    "row_of_record",
]

SCHEMA_NAME = "quadnav.Step"
"""The step channel's schema name."""

ROW_SCALARS = frozenset({
    "step", "action", "yaw_rad", "d_prev_m", "d_now_m", "progress_m", "deviation_m", "deviated",
    "collided", "reward", "outcome",
})
"""StepRecord fields that hold one value per vehicle ((N,) arrays); all others hold a row each
((N, k)). The one thing about a field that its type does not say."""

_DOUBLE, _INT32, _BOOL = 1, 5, 8  # descriptor.proto FieldDescriptorProto.Type
_OPTIONAL, _REPEATED = 1, 3


@dataclasses.dataclass(frozen=True)
class StepField:
    """One field of ``quadnav.Step``."""

    name: str
    number: int
    kind: str
    """``"f"`` (double), ``"i"`` (int32) or ``"b"`` (bool)."""
    repeated: bool
    optional: bool
    """The StepRecord field may be None (then left out)."""

    @property
    def key(self) -> bytes:
        """The field's key on the wire."""
        wire = 2 if self.repeated else {"f": 1, "i": 0, "b": 0}[self.kind]
        return _varint(self.number << 3 | wire)


def _varint(n: int) -> bytes:
    n &= (1 << 64) - 1  # a negative int32 is sign-extended to 64 bits, as protobuf does
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _kind(annotation: str, name: str) -> tuple[str, bool]:
    """(dtype kind, optional) of a StepRecord field from its annotation (``NDArray[np.float64]``)."""
    m = re.search(r"NDArray\[np\.(\w+)\]", str(annotation))
    if m is None:
        raise TypeError(f"StepRecord.{name}: annotation {annotation!r} is not an NDArray[np.<dtype>]")
    kind = np.dtype(getattr(np, m.group(1))).kind
    if kind not in "fib":
        raise TypeError(f"StepRecord.{name}: dtype {m.group(1)} has no quadnav.Step field type")
    return kind, "None" in str(annotation)


def _fields() -> tuple[StepField, ...]:
    out = [StepField("t_mono_s", 1, "f", False, False)]
    for f in dataclasses.fields(StepRecord):
        kind, optional = _kind(f.type, f.name)
        out.append(StepField(f.name, len(out) + 1, kind, f.name not in ROW_SCALARS, optional))
    out.append(StepField("latency_ms", len(out) + 1, "f", False, False))
    return tuple(out)


FIELDS: tuple[StepField, ...] = _fields()
"""``quadnav.Step``'s fields in number order."""


def _len_delimited(number: int, payload: bytes) -> bytes:
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def descriptor_set() -> bytes:
    """The schema: a ``FileDescriptorSet`` of ``quadnav/Step.proto`` (proto3, package ``quadnav``)."""
    types = {"f": _DOUBLE, "i": _INT32, "b": _BOOL}
    fields = b"".join(
        _len_delimited(2, b"".join([
            _len_delimited(1, f.name.encode()),
            _varint(3 << 3) + _varint(f.number),
            _varint(4 << 3) + _varint(_REPEATED if f.repeated else _OPTIONAL),
            _varint(5 << 3) + _varint(types[f.kind]),
        ]))
        for f in FIELDS
    )
    message = _len_delimited(1, b"Step") + fields
    file = b"".join([
        _len_delimited(1, b"quadnav/Step.proto"),
        _len_delimited(2, b"quadnav"),
        _len_delimited(4, message),
        _len_delimited(12, b"proto3"),
    ])
    return _len_delimited(1, file)


_D = struct.Struct("<d")
_F8 = np.dtype("<f8")
_PLAN = [(f.name, f.kind, f.repeated, f.key) for f in FIELDS]
_SMALL = [_varint(n) for n in range(4096)]
"""Varints of 0..4095, looked up: lengths, step indices, actions."""


def _wire(kind: str, v: np.ndarray) -> bytes:
    """The packed values of a float or bool array (raw little-endian bytes), or of an int array
    (varints)."""
    if kind == "f":
        return (v if v.dtype == _F8 else v.astype(_F8)).tobytes()
    if kind == "b":
        return v.astype(np.uint8, copy=False).tobytes()
    return b"".join(_varint(_int32(x)) for x in v.reshape(-1).tolist())


def _int32(v: Any) -> int:
    i = int(v.item() if isinstance(v, np.ndarray) else v)
    if not -(1 << 31) <= i < 1 << 31:
        raise ValueError(f"{i} does not fit quadnav.Step's int32")
    return i


def encode(row: Mapping[str, Any]) -> bytes:
    """One step as ``quadnav.Step`` bytes. ``row``: every field's value for this vehicle (a number
    or bool, a 1-D array or sequence, or None to leave it out; a single value may also come as a
    one-element array); a missing field is an error (KeyError)."""
    parts: list[bytes] = []
    for name, kind, repeated, key in _PLAN:
        v = row[name]
        if v is None:
            continue
        if repeated:
            data = _wire(kind, np.asarray(v))
            n = len(data)
            parts += (key, _SMALL[n] if n < 4096 else _varint(n), data)
        elif isinstance(v, np.ndarray) and v.size == 1 and kind != "i":
            parts += (key, _wire(kind, v))
        elif kind == "f":
            parts += (key, _D.pack(float(v)))
        elif kind == "b":
            parts += (key, b"\x01" if v else b"\x00")
        else:
            i = _int32(v)
            parts += (key, _SMALL[i] if 0 <= i < 4096 else _varint(i))
    return b"".join(parts)


_KIND_DTYPE = {"f": _F8, "b": np.dtype(np.bool_)}
_RECORD_PLAN = [(f.name, f.kind, f.repeated, f.key, _KIND_DTYPE.get(f.kind)) for f in FIELDS[1:-1]]
_T_KEY, _LATENCY_KEY = FIELDS[0].key, FIELDS[-1].key


def encode_record(t_mono_s: float, record: StepRecord, latency_ms: float) -> bytes:
    """A one-vehicle ``record`` (N = 1; else ValueError) decided at ``t_mono_s`` as ``quadnav.Step``
    bytes: what :func:`encode` of :func:`row_of_record` gives, straight from the arrays."""
    if record.n != 1:
        raise ValueError(f"a quadnav.Step holds one vehicle's step, the record holds {record.n}")
    parts = [_T_KEY, _D.pack(float(t_mono_s))]
    for name, kind, repeated, key, dtype in _RECORD_PLAN:
        v = getattr(record, name)
        if v is None:
            continue
        if dtype is None and not repeated:  # one int: a varint
            i = _int32(v)
            parts += (key, _SMALL[i] if 0 <= i < 4096 else _varint(i))
            continue
        # ints: varints; one row of doubles or bools: its bytes, little-endian (bools: 0 or 1)
        data = _wire(kind, v) if dtype is None else (v if v.dtype == dtype else v.astype(dtype)).tobytes()
        if repeated:
            n = len(data)
            parts += (key, _SMALL[n] if n < 4096 else _varint(n), data)
        else:
            parts += (key, data)
    parts += (_LATENCY_KEY, _D.pack(float(latency_ms)))
    return b"".join(parts)


def row_of_record(t_mono_s: float, record: StepRecord, latency_ms: float, i: int = 0) -> dict[str, Any]:
    """Vehicle ``i``'s values of ``record`` as :func:`encode` takes them (one-row slices: no copies)."""
    row: dict[str, Any] = {"t_mono_s": float(t_mono_s), "latency_ms": float(latency_ms)}
    whole = record.n == 1 and i == 0
    for name, *_ in _PLAN[1:-1]:
        v = getattr(record, name)
        row[name] = v if whole or v is None else v[i : i + 1]
    return row


def row_of_kwargs(t_mono_s: float, d: Mapping[str, Any]) -> dict[str, Any]:
    """The values of a step given as :meth:`FlightRecorder.step`'s keyword arguments (which predate
    :class:`StepRecord`): its ``reward_terms`` give ``d_prev_m``, ``d_now_m``, ``deviated`` and
    ``collided``; the primitive's heading gives ``yaw_rad``; what they do not say is NaN (floats),
    False (bools) or 0 (``outcome``: running)."""
    terms = d.get("reward_terms") or {}
    prim = d.get("primitive")
    nan3 = np.full(3, math.nan)
    row: dict[str, Any] = {
        "t_mono_s": float(t_mono_s),
        "latency_ms": float(d.get("latency_ms", math.nan)),
        "yaw_rad": math.nan if prim is None else float(prim[2]),
        "end_pos_world_m": nan3,
        "d_prev_m": float(terms.get("d_prev_m", math.nan)),
        "d_now_m": float(terms.get("d_now_m", math.nan)),
        "deviated": bool(terms.get("deviated", False)),
        "collided": bool(terms.get("collided", False)),
        "outcome": 0,
    }
    for f in FIELDS[1:-1]:
        if f.name not in row:
            row[f.name] = d.get(f.name)
    return row
