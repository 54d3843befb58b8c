"""Declared schemas for the JSON-like inputs: msgspec strict Structs with bounds, checked in one place.

`untrusted.py` keeps the byte-level gates (regular files, sizes, nesting depth, NaN/Infinity, absurd integers,
duplicate keys); what a parsed value must look like is declared as msgspec types (field names, types, number
bounds, lengths) next to the reader that needs it, and checked here by `decode`, whose one-line failure names the
field path: ``keyframes[3].time: expected a number <= 86400, got 1e+09``. msgspec's strict mode never coerces
(no "3" for 3, no true for 1); `number` is the one checker for a single number outside a schema.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from npga_core.errors import AvatarFileError, brief

#: Largest magnitude of a number read without a tighter bound (NaN and +-Inf fail every bound).
HUGE = 1e300

Finite = Annotated[float, Meta(ge=-HUGE, le=HUGE)]
Name = Annotated[str, Meta(min_length=1, max_length=128)]
Text = Annotated[str, Meta(max_length=4096)]
#: A file path named inside a file (sessions, settings): no NUL byte, shorter than 4096 characters.
_NO_NUL = "^[^\\x00]*$"
FilePath = Annotated[str, Meta(min_length=1, max_length=4095, pattern=_NO_NUL)]


class SchemaError(ValueError):
    """A value that does not match its declared schema; the text is "field.path: problem"."""


_NOUNS = {"float": "a number", "int": "an integer", "str": "a string", "array": "a list", "object": "an object",
          "bool": "a boolean", "null": "null", "bytes": "bytes"}
_TYPES = re.compile(r"`([a-z]+(?: \| [a-z]+)*)`")
_PATTERNS = {f"`str` matching regex {_NO_NUL!r}": "a path without NUL bytes"}
_STEP = re.compile(r"\.([^.\[]+)|\[(\d+|\.\.\.)\]")
_FLOAT = re.compile(r"(?<![\w.])(\d+\.\d+(?:e[+-]?\d+)?|\d+e[+-]?\d+)")


def _nouns(m: re.Match[str]) -> str:
    """msgspec's `float | null` as "a number or null" (anything else, a field's name, as it is)."""
    kinds = m.group(1).split(" | ")
    return " or ".join(_NOUNS[k] for k in kinds) if all(k in _NOUNS for k in kinds) else m.group(0)


def _value_at(value: Any, at: str) -> tuple[bool, Any]:
    """(found, the value) at msgspec's path `at` ("$.a[3].b") in the checked value."""
    for name, index in _STEP.findall(at.removeprefix("$")):
        if index == "...":
            return False, None
        try:
            value = value[int(index)] if index else (value[name] if isinstance(value, dict) else getattr(value, name))
        except (KeyError, IndexError, TypeError, AttributeError):
            return False, None
    return True, value


def _join(where: str, field: str) -> str:
    if not field:
        return where
    return f"{where}{field}" if not where or field.startswith("[") else f"{where}.{field}"


def problem(e: msgspec.ValidationError, value: Any, where: str = "") -> str:
    """msgspec's message as "field.path: problem" in words, with the value found there."""
    text = str(e)
    msg, sep, at = text.partition(" - at `")
    at = at.removesuffix("`") if sep else "$"
    if at.startswith("key") or "` in `" in at:  # "key` in `$.names": a dict key
        msg, at = msg.replace("`str`", "a name"), at.split("` in `")[-1]
    field = at.removeprefix("$").removeprefix(".")
    for k, v in _PATTERNS.items():
        msg = msg.replace(k, v)
    msg = _TYPES.sub(_nouns, msg)
    msg = _FLOAT.sub(lambda m: f"{float(m.group(1)):g}", msg).replace("Object", "object")
    msg = msg[:1].lower() + msg[1:]
    found, got = _value_at(value, at)
    if found and isinstance(got, float) and not math.isfinite(got):
        msg = "expected a finite number"
    elif found and ", got" not in msg and msg.startswith("expected") and not isinstance(got, dict | list):
        msg += f", got {brief(got)}"
    name = _join(where, field)
    return f"{name}: {msg}" if name else msg


def decode(value: Any, schema: Any, where: str = "") -> Any:
    """`value` (parsed JSON, or objects with attributes) as `schema` (a msgspec type); SchemaError naming the
    field path (after `where`) otherwise."""
    try:
        return msgspec.convert(value, schema, strict=True, from_attributes=True)
    except msgspec.ValidationError as e:
        raise SchemaError(problem(e, value, where)) from None


def decode_file(value: Any, schema: Any, path: str | Path, where: str = "") -> Any:
    """`decode` whose failure is an AvatarFileError naming `path` and the field path."""
    try:
        return decode(value, schema, where)
    except SchemaError as e:
        raise AvatarFileError(path, str(e)) from None


def number(value: Any, what: str, lo: float = -HUGE, hi: float = HUGE, whole: bool = False) -> Any:
    """The one number checker outside a schema: a finite number in [lo, hi] (bools refused; with `whole`, an
    integer, a float with an integral value accepted as one); SchemaError("what: problem") otherwise."""
    if whole and isinstance(value, float) and value.is_integer() and abs(value) <= 2**62:
        value = int(value)
    bounds = Meta(ge=int(max(lo, -2**62)), le=int(min(hi, 2**62))) if whole else Meta(ge=lo, le=hi)
    return decode(value, Annotated[int, bounds] if whole else Annotated[float, bounds], what)
