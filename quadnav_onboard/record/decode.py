"""Decode a record's messages with their own schemas, without generated code or ``protobuf``.

A protobuf schema in an MCAP file is a ``FileDescriptorSet`` (what Foxglove's SDK writes). This
module reads it with a small wire-format parser and decodes messages into dicts keyed by field
name, proto3 defaults filled in (0, "", b"", False, [], and None for an absent message field).
JSON messages are ``json.loads``. :class:`DecoderFactory` plugs both into the ``mcap`` library's
readers (``make_reader(f, decoder_factories=[DecoderFactory()])``).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.records import Schema

__all__ = ["DecodeError", "DecoderFactory", "ProtobufSchema", "decoder_for"]


class DecodeError(ValueError):
    """A schema or message that cannot be decoded (malformed bytes, unknown type)."""


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if i >= len(buf):
            raise DecodeError("truncated varint")
        b = buf[i]
        i += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, i
        shift += 7
        if shift > 63:
            raise DecodeError("varint longer than 10 bytes")


def _fields(buf: bytes) -> Iterator[tuple[int, int, Any]]:
    """(field number, wire type, value): an int for varint/fixed, bytes for length-delimited."""
    i, n = 0, len(buf)
    while i < n:
        key, i = _varint(buf, i)
        num, wt = key >> 3, key & 7
        if wt == 0:
            v, i = _varint(buf, i)
        elif wt == 1:
            if i + 8 > n:
                raise DecodeError("truncated fixed64")
            v, i = buf[i : i + 8], i + 8
        elif wt == 2:
            ln, i = _varint(buf, i)
            if i + ln > n:
                raise DecodeError("truncated length-delimited field")
            v, i = buf[i : i + ln], i + ln
        elif wt == 5:
            if i + 4 > n:
                raise DecodeError("truncated fixed32")
            v, i = buf[i : i + 4], i + 4
        else:
            raise DecodeError(f"unsupported wire type {wt}")
        yield num, wt, v


# descriptor.proto field types
_DOUBLE, _FLOAT, _INT64, _UINT64, _INT32, _FIXED64, _FIXED32, _BOOL, _STRING = range(1, 10)
_MESSAGE, _BYTES, _UINT32, _ENUM, _SFIXED32, _SFIXED64, _SINT32, _SINT64 = range(11, 19)
_VARINTS = {_INT64, _UINT64, _INT32, _BOOL, _UINT32, _ENUM, _SINT32, _SINT64}
_FIXED = {_DOUBLE: "<d", _FIXED64: "<Q", _SFIXED64: "<q", _FLOAT: "<f", _FIXED32: "<I", _SFIXED32: "<i"}
_LABEL_REPEATED = 3
_DECODE_ERRORS = (DecodeError, struct.error, UnicodeDecodeError, AttributeError, TypeError, RecursionError)
"""What damaged bytes raise while decoding (a string field arriving as a number, ...)."""


@dataclass(frozen=True)
class _Field:
    name: str
    type: int
    repeated: bool
    type_name: str  # fully qualified, no leading dot ("foxglove.Vector3"), messages and enums


def _scalar(ftype: int, v: Any) -> Any:
    if ftype in _FIXED:
        return struct.unpack(_FIXED[ftype], v)[0]
    if ftype == _BOOL:
        return bool(v)
    if ftype in (_INT64, _INT32, _ENUM):
        return v - (1 << 64) if v >= 1 << 63 else v
    if ftype in (_SINT32, _SINT64):
        return (v >> 1) ^ -(v & 1)
    return v


def _default(f: _Field) -> Any:
    if f.repeated:
        return []
    if f.type == _MESSAGE:
        return None
    if f.type == _STRING:
        return ""
    if f.type == _BYTES:
        return b""
    if f.type == _BOOL:
        return False
    return 0.0 if f.type in (_DOUBLE, _FLOAT) else 0


class ProtobufSchema:
    """The message types of one ``FileDescriptorSet``; :meth:`decode` turns bytes into a dict."""

    def __init__(self, descriptor_set: bytes) -> None:
        self.messages: dict[str, dict[int, _Field]] = {}
        try:
            for num, _, file_bytes in _fields(descriptor_set):
                if num == 1:
                    self._file(bytes(file_bytes))
        except (DecodeError, UnicodeDecodeError, TypeError) as exc:
            raise DecodeError(f"malformed FileDescriptorSet: {exc}") from None

    def _file(self, buf: bytes) -> None:
        package = ""
        types = []
        for num, _, v in _fields(buf):
            if num == 2:
                package = bytes(v).decode()
            elif num == 4:
                types.append(bytes(v))
        for t in types:
            self._message(t, package)

    def _message(self, buf: bytes, scope: str) -> None:
        name, fields, nested = "", {}, []
        for num, _, v in _fields(buf):
            if num == 1:
                name = bytes(v).decode()
            elif num == 2:
                f = self._field(bytes(v))
                fields[f[0]] = f[1]
            elif num == 3:
                nested.append(bytes(v))
        full = f"{scope}.{name}" if scope else name
        self.messages[full] = fields
        for n in nested:
            self._message(n, full)

    @staticmethod
    def _field(buf: bytes) -> tuple[int, _Field]:
        name, number, label, ftype, type_name = "", 0, 1, 0, ""
        for num, _, v in _fields(buf):
            if num == 1:
                name = bytes(v).decode()
            elif num == 3:
                number = v
            elif num == 4:
                label = v
            elif num == 5:
                ftype = v
            elif num == 6:
                type_name = bytes(v).decode().lstrip(".")
        return number, _Field(name, ftype, label == _LABEL_REPEATED, type_name)

    @property
    def numbers(self) -> dict[str, dict[str, int]]:
        """Field numbers by message type and field name (``numbers["foxglove.Point3"]["x"]``)."""
        return {t: {f.name: n for n, f in spec.items()} for t, spec in self.messages.items()}

    def decode(self, type_name: str, data: bytes, *, strict: bool = False) -> dict[str, Any]:
        """Decode ``data`` as message ``type_name`` (e.g. ``foxglove.RawImage``). Fields the schema
        does not declare are skipped, as protobuf does, or with ``strict`` are an error."""
        try:
            return self._decode(type_name, bytes(data), strict)
        except _DECODE_ERRORS as exc:
            raise DecodeError(f"{type_name}: {type(exc).__name__}: {exc}") from None

    def _decode(self, type_name: str, data: bytes, strict: bool) -> dict[str, Any]:
        spec = self.messages.get(type_name)
        if spec is None:
            raise DecodeError(f"message type {type_name!r} is not in the schema")
        out = {f.name: _default(f) for f in spec.values()}
        for num, wt, v in _fields(data):
            f = spec.get(num)
            if f is None:
                if strict:
                    raise DecodeError(f"field {num} is not declared by {type_name}")
                continue
            if f.type == _MESSAGE:
                val: Any = self._decode(f.type_name, v, strict)
            elif f.type == _STRING:
                val = v.decode()
            elif f.type == _BYTES:
                val = v
            elif wt == 2 and f.repeated:  # packed scalars
                out[f.name].extend(self._packed(f.type, v))
                continue
            else:
                val = _scalar(f.type, v)
            if f.repeated:
                out[f.name].append(val)
            else:
                out[f.name] = val
        return out

    @staticmethod
    def _packed(ftype: int, buf: bytes) -> list[Any]:
        if ftype in _FIXED:
            fmt = _FIXED[ftype]
            size = struct.calcsize(fmt)
            if len(buf) % size:
                raise DecodeError("packed field of a length that is not a multiple of its item")
            return list(struct.unpack(f"<{len(buf) // size}{fmt[1]}", buf))
        if ftype not in _VARINTS:
            raise DecodeError(f"field type {ftype} cannot be packed")
        vals, i = [], 0
        while i < len(buf):
            v, i = _varint(buf, i)
            vals.append(_scalar(ftype, v))
        return vals


_SCHEMA_CACHE: dict[tuple[str, bytes], ProtobufSchema] = {}


def decoder_for(message_encoding: str, schema: Schema | None) -> Callable[[bytes], Any] | None:
    """A decoder of the channel's messages: protobuf (by its schema) or JSON; None for others."""
    if message_encoding == "json":
        return json.loads
    if message_encoding != "protobuf" or schema is None or schema.encoding != "protobuf":
        return None
    key = (schema.name, bytes(schema.data))
    parsed = _SCHEMA_CACHE.get(key)
    if parsed is None:
        parsed = _SCHEMA_CACHE[key] = ProtobufSchema(key[1])
    name = schema.name

    def decode(data: bytes) -> dict[str, Any]:
        return parsed.decode(name, data)

    return decode


class DecoderFactory(McapDecoderFactory):
    """``mcap`` decoder factory for the records' protobuf (by schema) and JSON messages."""

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], Any] | None:
        return decoder_for(message_encoding, schema)
