"""Typed JSON files: frozen dataclasses read from and written to a JSON object, every key checked.

A `Record` subclass declares its keys as dataclass fields, in the order they are written, with
their JSON types as annotations (`str`, `int`, `float` (an integer is a number too), `bool`,
`X | None`, `list[X]`, `tuple[X, ...]` (written as a list), `dict[str, X]`, another `Record`, and
`JSON`: any JSON value, kept as it is, for the few objects a record copies from elsewhere, such
as a capture's sidecar). `from_json` refuses a missing key, a key of the wrong type and a key the record does
not know with a `FormatError` naming the file and the key (`captures[0].sha256`), never a
KeyError; `to_json` writes the keys back in field order, values as they were read (numbers are
never converted; a non-finite one, which only a record made in memory holds, is written as
null; a numpy scalar is written as the Python number), so a file read and written again is the
same JSON. The fields named in
`OMITTED_WHEN_NONE` are keys some writers leave out: absent on reading, they are None and are
not written. The fields named in `IN_MEMORY` are no keys at all: a record made in memory holds
them (an edge's levels as the edge finder saw them), a record read holds their defaults, and
they are never written.

The result and diagnosis files carry a `schema` tag, `"bench-ctl/KIND/N"`; `schema_version`
reads it (docs/formats.md).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Mapping
from typing import Any, ClassVar, NewType, TypeVar, Union

import numpy as np

from bench_ctl.exitcodes import BadInput

__all__ = ["FormatError", "JSON", "Record", "plain", "schema_version"]

R = TypeVar("R", bound="Record")

#: any JSON value (null, true / false, a number, a string, a list or an object of JSON values),
#: checked as such and kept as it is: a key whose content a record copies from elsewhere (a
#: capture's sidecar, an optimizer's settings)
JSON = NewType("JSON", object)


class FormatError(BadInput):
    """A JSON file that is not the record it should be; the message names the file and the key."""


def _describe(tp: Any) -> str:
    """The JSON type an annotation stands for, in words."""
    if tp is Any:
        return "any value"
    if _is_json(tp):
        return "a JSON value"
    if tp is type(None):
        return "null"
    if tp is bool:
        return "true or false"
    if tp is int:
        return "an integer"
    if tp is float:
        return "a number"
    if tp is str:
        return "a string"
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        return " or ".join(_describe(a) for a in typing.get_args(tp))
    if origin in (list, tuple):
        return f"a list of {_describe(typing.get_args(tp)[0])}"
    if origin is dict:
        return f"an object of {_describe(typing.get_args(tp)[1])}"
    if isinstance(tp, type) and issubclass(tp, Record):
        return "an object"
    return str(tp)


def _key(path: str, sub: str | int) -> str:
    return f"{path}[{sub}]" if isinstance(sub, int) else (f"{path}.{sub}" if path else sub)


def _read(value: Any, tp: Any, key: str, where: str) -> Any:
    """`value` checked against the annotation `tp` (records built, lists of records as tuples)."""
    def wrong() -> FormatError:
        shown = repr(value)
        shown = shown if len(shown) <= 60 else shown[:57] + "..."
        return FormatError(f"{where}: key {key!r} must be {_describe(tp)}, got {shown}")

    if tp is Any:
        return value
    if _is_json(tp):
        if not _json_value(value):
            raise wrong()
        return value
    if tp is type(None):
        if value is not None:
            raise wrong()
        return None
    if tp is bool:
        if not isinstance(value, bool):
            raise wrong()
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong()
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise wrong()
        return value
    if tp is str:
        if not isinstance(value, str):
            raise wrong()
        return value
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        options = typing.get_args(tp)
        if value is None and type(None) in options:
            return None
        for option in (o for o in options if o is not type(None)):
            try:
                return _read(value, option, key, where)
            except FormatError:
                if _is_container(option) and isinstance(value, (dict, list)):
                    raise   # the key inside is the one to name
        raise wrong()
    if origin in (list, tuple):
        if not isinstance(value, list):
            raise wrong()
        inner = typing.get_args(tp)[0]
        items = [_read(v, inner, _key(key, i), where) for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise wrong()
        inner = typing.get_args(tp)[1]
        return {k: _read(v, inner, _key(key, k), where) for k, v in value.items()}
    if isinstance(tp, type) and issubclass(tp, Record):
        if not isinstance(value, dict):
            raise wrong()
        return tp._from(value, key, where)
    raise TypeError(f"unsupported annotation {tp!r}")


def _is_json(tp: Any) -> bool:
    return tp is JSON


def _json_value(v: Any) -> bool:
    """Whether `v` is a JSON value as `json.loads` gives it (or a record made in memory holds)."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return True
    if isinstance(v, (list, tuple)):
        return all(_json_value(x) for x in v)
    if isinstance(v, dict):
        return all(isinstance(k, str) and _json_value(x) for k, x in v.items())
    return False


def _is_container(tp: Any) -> bool:
    return typing.get_origin(tp) in (list, tuple, dict) or (isinstance(tp, type) and issubclass(tp, Record))


def _write(value: Any) -> Any:
    if isinstance(value, np.generic):   # a numpy scalar a writer passed on: the Python number
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Record):
        return value.to_json()
    if isinstance(value, (list, tuple)):
        return [_write(v) for v in value]
    if isinstance(value, dict):
        return {k: _write(v) for k, v in value.items()}
    return value


@functools.cache
def _layout(cls: type) -> tuple[dict[str, Any], tuple[dataclasses.Field, ...]]:
    """A record class's annotations (resolved) and fields, worked out once."""
    return typing.get_type_hints(cls), tuple(f for f in dataclasses.fields(cls)
                                             if f.init and f.name not in cls.IN_MEMORY)


class Record:
    """Base of a typed JSON object; subclasses are frozen dataclasses (see the module docstring)."""

    #: keys a writer may leave out: None when absent, not written when None
    OMITTED_WHEN_NONE: ClassVar[tuple[str, ...]] = ()
    #: fields that are no keys: held in memory, never read nor written (they need defaults)
    IN_MEMORY: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def _from(cls: type[R], data: Mapping[str, Any], path: str, where: str) -> R:
        hints, fields = _layout(cls)
        names = {f.name for f in fields}
        unknown = [k for k in data if k not in names]
        if unknown:
            raise FormatError(f"{where}: unknown key(s) {', '.join(repr(_key(path, k)) for k in unknown)}"
                              f" in {'the file' if not path else repr(path)}; known: {', '.join(sorted(names))}")
        kwargs = {}
        for f in fields:
            key = _key(path, f.name)
            if f.name not in data:
                if f.name in cls.OMITTED_WHEN_NONE:
                    kwargs[f.name] = None
                    continue
                raise FormatError(f"{where}: key {key!r} is missing ({_describe(hints[f.name])})")
            kwargs[f.name] = _read(data[f.name], hints[f.name], key, where)
        return cls(**kwargs)

    @classmethod
    def from_json(cls: type[R], data: Any, where: str = "") -> R:
        """The record held in the JSON value `data`; `where` (the file) starts every error message."""
        where = where or f"a {cls.__name__}"
        if not isinstance(data, dict):
            raise FormatError(f"{where}: expected a JSON object, got {type(data).__name__}")
        return cls._from(data, "", where)

    def to_json(self) -> dict[str, Any]:
        """The JSON object: every key in field order (those of OMITTED_WHEN_NONE only when set,
        those of IN_MEMORY never)."""
        out = {}
        for f in dataclasses.fields(self):   # type: ignore[arg-type]
            if f.name in self.IN_MEMORY:
                continue
            value = getattr(self, f.name)
            if value is None and f.name in self.OMITTED_WHEN_NONE:
                continue
            out[f.name] = _write(value)
        return out


def schema_version(data: Mapping[str, Any], kind: str, supported: int, where: str) -> int:
    """The version N of `data`'s `schema` tag "bench-ctl/KIND/N", checked: a file without the tag
    is read as version 1 (the tag came with the first version, so its keys are version 1's); a
    tag of another kind or a version this bench-ctl does not read is refused, naming both."""
    expected = f"bench-ctl/{kind}/{supported}"
    if "schema" not in data:
        return 1
    tag = data["schema"]
    prefix = f"bench-ctl/{kind}/"
    if not isinstance(tag, str) or not tag.startswith(prefix) or not tag[len(prefix):].isdigit():
        raise FormatError(f"{where}: key 'schema' is {tag!r}, expected {expected!r} (not a {kind} file)")
    version = int(tag[len(prefix):])
    if version != supported:
        raise FormatError(f"{where}: key 'schema' is {tag!r}, expected {expected!r}: this bench-ctl reads "
                          f"{kind} files of version {supported}, the file is version {version}")
    return version


def plain(x: Any) -> Any:
    """`x` as a record holds it: numpy scalars as Python numbers, tuples as lists; non-finite
    numbers stay as they are in memory (`to_json` writes them as null)."""
    if isinstance(x, dict):
        return {k: plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x
