"""The configuration reference, generated from the config dataclasses themselves.

Every key of a config tree (a frozen dataclass such as
:class:`~quadnav_onboard.daemon.config.FlightConfig`, and the dataclasses it nests) is listed with
its type and range (from the annotation), its default, its unit (from the name's suffix or the
docstring) and its meaning (the docstring written under the field). Field docstrings are not
runtime attributes, so they are read from the class source with :mod:`ast`.

Two renderings: :func:`commented_yaml` (``quadnav-onboard --print-config``: a YAML of the defaults
that loads back into them, each key with its docstring as a comment) and :func:`markdown_reference`
(docs/configuration.md, one table per section; ``python scripts/gen_config_reference.py``).
A field without a docstring is refused (:class:`MissingDocstringError`, naming class and field):
the reference cannot silently lose a key's meaning.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import json
import re
import textwrap
import types
import typing
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Annotated, Any, Literal

import yaml

__all__ = [
    "FieldDoc",
    "MissingDocstringError",
    "Section",
    "commented_yaml",
    "field_docstrings",
    "flight_config_yaml",
    "markdown_reference",
    "missing_docstrings",
    "sections",
]


class MissingDocstringError(ValueError):
    """A config field has no docstring under it; the message names each such class and field."""


@dataclass(frozen=True)
class FieldDoc:
    """One key of a config section, as the reference shows it."""

    key: str
    """The key inside its section."""
    type: str
    """The type, with the range its annotation states (e.g. ``float in (0, 5]``)."""
    default: Any
    """The default value (None for a nested section that defaults to null)."""
    unit: str
    """Unit (``m``, ``s``, ``Hz``, ...) or ``""`` where the value has none."""
    doc: str
    """The field's docstring, whitespace collapsed."""


@dataclass(frozen=True)
class Section:
    """One config dataclass at one key path of the tree (``""`` for the root)."""

    path: str
    cls: type
    doc: str
    """The first paragraph of the class docstring."""
    nullable: bool
    """The section's key defaults to null (e.g. ``shield``: what the checkpoint records)."""
    fields: tuple[FieldDoc, ...]


@cache
def field_docstrings(cls: type) -> dict[str, str]:
    """The docstring under each annotated field of ``cls`` (its own body and its dataclass bases)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        node = ast.parse(source).body[0]
        if not isinstance(node, ast.ClassDef):
            continue
        for prev, cur in zip(node.body, node.body[1:], strict=False):
            if (
                isinstance(prev, ast.AnnAssign)
                and isinstance(prev.target, ast.Name)
                and isinstance(cur, ast.Expr)
                and isinstance(cur.value, ast.Constant)
                and isinstance(cur.value.value, str)
            ):
                docs[prev.target.id] = " ".join(cur.value.value.split())
    return docs


def _strip_optional(tp: Any) -> tuple[Any, bool]:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(args) < len(typing.get_args(tp)):
            return args[0], True
    return tp, False


def _range(metadata: Sequence[Any]) -> str:
    lo = hi = ""
    for m in metadata:
        for item in [m, *getattr(m, "metadata", [])]:
            for attr, side, bracket in (
                ("ge", "lo", "["),
                ("gt", "lo", "("),
                ("le", "hi", "]"),
                ("lt", "hi", ")"),
            ):
                value = getattr(item, attr, None)
                if value is not None and not callable(value):
                    text = f"{value:g}" if isinstance(value, float) else str(value)
                    if side == "lo":
                        lo = f"{bracket}{text}"
                    else:
                        hi = f"{text}{bracket}"
    if not lo and not hi:
        return ""
    return f"{lo or '(-inf'}, {hi or 'inf)'}"


def type_text(tp: Any) -> str:
    """A short type with its range: ``float in (0, 5]``, ``int | null``, ``"uvc" | "replay"``."""
    tp, optional = _strip_optional(tp)
    origin = typing.get_origin(tp)
    if origin is Annotated:
        base, *meta = typing.get_args(tp)
        text = type_text(base)
        bounds = _range(meta)
        lengths = [(getattr(m, "min_length", None), getattr(m, "max_length", None)) for m in meta]
        text = f"{text} in {bounds}" if bounds else text
        for lo, hi in lengths:
            if lo is not None or hi is not None:
                text += f", {lo or 0} to {hi if hi is not None else 'any'} items"
    elif origin is Literal:
        text = " | ".join(json.dumps(a) for a in typing.get_args(tp))
    elif origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            text = f"list of ({type_text(args[0])})"
        elif args and all(a == args[0] for a in args):
            text = f"[{len(args)} x {type_text(args[0])}]"
        else:
            text = "[" + ", ".join(type_text(a) for a in args) + "]"
    elif origin is dict:
        text = "mapping"
    elif dataclasses.is_dataclass(tp):
        text = "section"
    elif isinstance(tp, type):
        text = tp.__name__
    else:
        text = str(tp)
    return f"{text} | null" if optional else text


_SUFFIX_UNITS = (
    ("_m_s2", "m/s²"),
    ("_m_s", "m/s"),
    ("_rad_s", "rad/s"),
    ("_hz", "Hz"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_mm", "mm"),
    ("_ms", "ms"),
    ("_px", "px"),
    ("_m", "m"),
    ("_s", "s"),
)
_DOC_UNIT = re.compile(r"\((m/s\^?2?|m/s|rad/s|Hz|deg|rad|mm|ms|px|m|s)\b[,)]")


def unit_of(name: str, doc: str) -> str:
    """The unit a field's value is in: from the name's suffix (``_m``, ``_s``, ``_hz``, ...), else
    the first parenthesised unit in its docstring (``"Frame width (px)"``), else ``""``."""
    for suffix, unit in _SUFFIX_UNITS:
        if name.endswith(suffix):
            return unit
    m = _DOC_UNIT.search(doc)
    return m.group(1) if m else ""


def _first_paragraph(doc: str | None) -> str:
    return " ".join((doc or "").strip().split("\n\n")[0].split())


def _nested_class(tp: Any) -> tuple[type | None, bool]:
    base, optional = _strip_optional(tp)
    if typing.get_origin(base) is Annotated:
        base = typing.get_args(base)[0]
    return (base if dataclasses.is_dataclass(base) and isinstance(base, type) else None), optional


def _default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _plain(value: Any) -> Any:
    """A default as YAML/JSON shows it (tuples as lists, dataclasses as mappings)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {k: _plain(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def missing_docstrings(root: type) -> list[str]:
    """``Class.field`` of every field in the tree under ``root`` that has no docstring."""
    out: list[str] = []
    seen: set[type] = set()

    def walk(cls: type) -> None:
        if cls in seen:
            return
        seen.add(cls)
        docs = field_docstrings(cls)
        hints = typing.get_type_hints(cls, include_extras=True)
        fields = dataclasses.fields(cls)
        out.extend(f"{cls.__module__}.{cls.__qualname__}.{f.name}" for f in fields if not docs.get(f.name))
        for f in fields:
            nested, _ = _nested_class(hints[f.name])
            if nested is not None:
                walk(nested)

    walk(root)
    return out


def sections(root: type, path: str = "", nullable: bool = False) -> Iterator[Section]:
    """The sections of the tree under ``root``, depth first, the root first; a field without a
    docstring raises :class:`MissingDocstringError` naming all of them."""
    if not path:
        missing = missing_docstrings(root)
        if missing:
            raise MissingDocstringError(
                "config fields without a docstring (write one under each field: it is the key's "
                "meaning in the reference): " + ", ".join(missing)
            )
    docs = field_docstrings(root)
    hints = typing.get_type_hints(root, include_extras=True)
    rows: list[FieldDoc] = []
    nested: list[tuple[str, type, bool]] = []
    for f in dataclasses.fields(root):
        tp = hints[f.name]
        doc = docs[f.name]
        sub, optional = _nested_class(tp)
        default = _default(f)
        rows.append(FieldDoc(f.name, type_text(tp), _plain(default), unit_of(f.name, doc), doc))
        if sub is not None:
            nested.append((f"{path}.{f.name}" if path else f.name, sub, optional and default is None))
    yield Section(path, root, _first_paragraph(root.__doc__), nullable, tuple(rows))
    for sub_path, sub, sub_nullable in nested:
        yield from sections(sub, sub_path, sub_nullable)


def _yaml_value(value: Any) -> str:
    if value is dataclasses.MISSING:
        return "  # required"
    text = yaml.safe_dump(value, default_flow_style=True, sort_keys=False, allow_unicode=True, width=10_000)
    return text.strip().removesuffix("...").strip()


def _comment(text: str, indent: str, width: int = 100) -> list[str]:
    return [indent + "# " + line for line in textwrap.wrap(text, max(40, width - len(indent) - 2))]


def commented_yaml(root: type, title: str = "") -> str:
    """A YAML document of ``root``'s defaults, every key under a comment with its type, unit and
    meaning. A nested section whose default is null (e.g. ``shield``) is written ``key: null``
    with its keys commented out below it, at their defaults, ready to be uncommented; so the text
    loads back into the defaults (tests/test_config_reference.py)."""
    all_sections = {s.path: s for s in sections(root)}
    lines: list[str] = []
    if title:
        lines += [*_comment(title, ""), ""]

    def emit(section: Section, depth: int, commented: bool) -> None:
        indent = "  " * depth
        prefix = "# " if commented else ""
        for fd in section.fields:
            sub_path = f"{section.path}.{fd.key}" if section.path else fd.key
            sub = all_sections.get(sub_path)
            unit = f", {fd.unit}" if fd.unit else ""
            lines.extend(_comment(f"{fd.key} ({fd.type}{unit}): {fd.doc}", indent))
            if sub is not None and sub.nullable:
                lines.append(f"{indent}{prefix}{fd.key}: null")
                lines.append(f"{indent}# {fd.key}:  # its keys, at their defaults:")
                emit(sub, depth + 1, True)
            elif sub is not None:
                lines.append(f"{indent}{prefix}{fd.key}:")
                emit(sub, depth + 1, commented)
            else:
                lines.append(f"{indent}{prefix}{fd.key}: {_yaml_value(fd.default)}")

    emit(all_sections[""], 0, False)
    return "\n".join(lines) + "\n"


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_default(value: Any) -> str:
    if value is dataclasses.MISSING:
        return "required"
    if isinstance(value, dict):
        return "(section)"
    return "`" + _md_cell(_yaml_value(value)) + "`"


def markdown_reference(roots: Sequence[tuple[str, type, str]], header: str) -> str:
    """Markdown: ``header``, then for each ``(title, root class, intro)`` one table per section
    (key, type and range, default, unit, meaning)."""
    out = [header.rstrip(), ""]
    for title, root, intro in roots:
        out += [f"## {title}", "", intro.strip(), ""]
        for s in sections(root):
            heading = f"`{s.path}`" if s.path else f"top level (`{root.__name__}`)"
            out += [f"### {heading}", ""]
            note = f"{s.doc}" + (" The key defaults to `null` (see its row above)." if s.nullable else "")
            out += [f"{note} (`{s.cls.__module__}.{s.cls.__qualname__}`)", ""]
            out += ["| key | type | default | unit | meaning |", "|---|---|---|---|---|"]
            for fd in s.fields:
                out.append(
                    f"| `{fd.key}` | {_md_cell(fd.type)} | {_md_default(fd.default)} | {fd.unit or '—'} "
                    f"| {_md_cell(fd.doc)} |"
                )
            out.append("")
    return "\n".join(out).rstrip() + "\n"


def flight_config_yaml() -> str:
    """``quadnav-onboard --print-config``: the flight config's defaults as a commented YAML."""
    from quadnav_onboard.daemon.config import FlightConfig

    return commented_yaml(
        FlightConfig,
        "quadnav-onboard flight config: every key at its default, each with its type, range, unit and "
        "meaning (docs/configuration.md). mission.waypoints_m is required for a flight; a key left out "
        "takes its default.",
    )
