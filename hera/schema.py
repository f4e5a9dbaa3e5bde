"""Declared tables of settings: one declaration gives parsing, defaults, docs and errors.

A :class:`Table` is a list of :class:`Setting` (key, kind, default, doc). Parsing a raw
mapping (a TOML table, a measure's ``args``) against it:

- refuses unknown keys, naming the key and listing the known ones;
- converts and checks every value with the setting's :class:`Kind`, naming the key, the
  value and what is allowed;
- fills in defaults;
- collects **every** problem of the table (the caller decides how to report them), each
  one sentence that starts with where it was found (``spec.toml: [cluster]: ...``).

The README's reference tables are rendered from the same declarations (:meth:`Table.markdown`),
so the documentation cannot drift from what the parser accepts.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()
"""Default of a setting that must be given."""


class SchemaError(ValueError):
    """One or more problems with declared settings; ``problems`` holds one sentence each."""

    def __init__(self, problems: Sequence[str]) -> None:
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


@dataclass(frozen=True)
class Kind:
    """What values a setting takes: a name for the docs and a converter.

    ``convert(value)`` returns the converted value or raises ValueError with a short
    phrase saying what is allowed (e.g. ``"must be a number > 0"``).
    """

    name: str
    convert: Callable[[Any], Any]


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def number(
    minimum: float | None = None,
    maximum: float | None = None,
    *,
    above: float | None = None,
    integer: bool = False,
) -> Kind:
    """A finite number (an integer if ``integer``) within the given bounds."""
    parts = []
    if above is not None:
        parts.append(f"> {above:g}")
    if minimum is not None:
        parts.append(f">= {minimum:g}")
    if maximum is not None:
        parts.append(f"<= {maximum:g}")
    what = ("an integer" if integer else "a number") + (f" {' and '.join(parts)}" if parts else "")

    def convert(v: Any) -> Any:
        if not _is_number(v) or (integer and not isinstance(v, int)):
            raise ValueError(f"must be {what}")
        if (
            (above is not None and not v > above)
            or (minimum is not None and v < minimum)
            or (maximum is not None and v > maximum)
        ):
            raise ValueError(f"must be {what}")
        return int(v) if integer else float(v)

    return Kind(what, convert)


def _boolean(v: Any) -> bool:
    if not isinstance(v, bool):
        raise ValueError("must be true or false")
    return v


BOOL = Kind("true or false", _boolean)


def text(check: Callable[[str], Any] | None = None, what: str = "a string") -> Kind:
    """A string; ``check`` may raise ValueError with its own message."""

    def convert(v: Any) -> str:
        if not isinstance(v, str):
            raise ValueError(f"must be {what}")
        if check is not None:
            check(v)
        return v

    return Kind(what, convert)


STR = text()


def choice(*options: str) -> Kind:
    """One of ``options``."""
    what = "one of " + ", ".join(options)

    def convert(v: Any) -> str:
        if v not in options:
            raise ValueError(f"must be {what}")
        return v

    return Kind(what, convert)


def list_of(item: Kind, what: str | None = None) -> Kind:
    """A list whose items are each ``item`` (``what`` names it in messages and docs)."""
    what = what or f"a list whose items are {item.name}"

    def convert(v: Any) -> tuple:
        if not isinstance(v, (list, tuple)):
            raise ValueError(f"must be {what}")
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item.convert(x))
            except ValueError as e:
                raise ValueError(f"item {i + 1} {e}") from None
        return tuple(out)

    return Kind(what, convert)


def _table(v: Any) -> dict:
    if not isinstance(v, Mapping):
        raise ValueError("must be a table")
    return dict(v)


TABLE = Kind("a table", _table)


def either(a: Kind, b: Kind) -> Kind:
    """A value that ``a`` or ``b`` accepts (``a`` tried first)."""

    def convert(v: Any) -> Any:
        try:
            return a.convert(v)
        except ValueError:
            try:
                return b.convert(v)
            except ValueError:
                raise ValueError(f"must be {a.name} or {b.name}") from None

    return Kind(f"{a.name} or {b.name}", convert)


ANY = Kind("any value", lambda v: v)


@dataclass(frozen=True)
class Setting:
    """One declared setting: ``key``, its ``kind``, its ``default`` (:data:`REQUIRED` if it
    must be given, None for "not set") and a one-line ``doc``. ``attr`` names the attribute
    the value goes to when it differs from the key."""

    key: str
    kind: Kind
    default: Any
    doc: str
    attr: str | None = None

    @property
    def target(self) -> str:
        return self.attr or self.key

    def default_text(self) -> str:
        if self.default is REQUIRED:
            return "required"
        if self.default is None:
            return "-"
        if isinstance(self.default, bool):
            return "true" if self.default else "false"
        if isinstance(self.default, str):
            return f'"{self.default}"'
        if isinstance(self.default, (list, tuple)):
            return "[" + ", ".join(map(repr, self.default)) + "]"
        if isinstance(self.default, dict):
            return "{}"
        return f"{self.default:g}" if isinstance(self.default, float) else str(self.default)


def did_you_mean(word: str, known: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest known word, or an empty string."""
    import difflib

    close = difflib.get_close_matches(word, list(known), n=1, cutoff=0.75)
    return f" (did you mean {close[0]!r}?)" if close else ""


class Table:
    """A declared table of settings (see the module docstring)."""

    def __init__(self, title: str, settings: Sequence[Setting]) -> None:
        self.title = title
        self.settings = tuple(settings)
        self.by_key = {s.key: s for s in self.settings}
        if len(self.by_key) != len(self.settings):
            raise ValueError(f"{title}: a key is declared twice")

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(self.by_key)

    def only(self, *keys: str) -> Table:
        """A table of some of these settings (same declarations)."""
        return Table(self.title, [self.by_key[k] for k in keys])

    def without(self, *keys: str) -> Table:
        """A table of these settings less ``keys`` (same declarations)."""
        return Table(self.title, [s for s in self.settings if s.key not in keys])

    def unknown(self, raw: Mapping[str, Any], where: str) -> list[str]:
        """One problem per key of ``raw`` that the table does not declare."""
        known = ", ".join(self.keys) or "none"
        return [
            f"{where}: unknown key {k!r}{did_you_mean(str(k), self.keys)}; known keys: {known}"
            for k in raw
            if k not in self.by_key
        ]

    def parse(
        self,
        raw: Any,
        where: str,
        problems: list[str] | None = None,
        defaults: bool = True,
    ) -> dict[str, Any]:
        """The converted settings of ``raw`` by attribute name, defaults filled in (unless
        ``defaults`` is false: then only the keys given).

        Problems go to ``problems`` (one sentence each, starting with ``where``); without
        a list, the first problems raise :class:`SchemaError`. Keys with problems are left
        out of the result.
        """
        own = problems is None
        found: list[str] = [] if own else problems  # type: ignore[assignment]
        if raw is None:
            raw = {}
        if not isinstance(raw, Mapping):
            found.append(f"{where}: must be a table, got {_show(raw)}")
            raw = {}
        found.extend(self.unknown(raw, where))
        out: dict[str, Any] = {}
        for s in self.settings:
            if s.key in raw and raw[s.key] is None and s.default is None:
                out[s.target] = None  # "not set", as parsed before (parsing is idempotent)
            elif s.key in raw:
                try:
                    out[s.target] = s.kind.convert(raw[s.key])
                except ValueError as e:
                    found.append(f"{where}: {s.key} {e}, got {_show(raw[s.key])}")
            elif s.default is REQUIRED:
                found.append(f"{where}: {s.key} is required ({s.doc})")
            elif defaults:
                out[s.target] = _copy(s.default)
        if own and found:
            raise SchemaError(found)
        return out

    def markdown(self) -> str:
        """The table as Markdown rows: key, kind, default, meaning."""
        lines = ["| key | value | default | meaning |", "|---|---|---|---|"]
        for s in self.settings:
            lines.append(f"| `{s.key}` | {s.kind.name} | {s.default_text()} | {s.doc} |")
        return "\n".join(lines)


def _copy(value: Any) -> Any:
    if isinstance(value, dict):
        return dict(value)
    if isinstance(value, list):
        return list(value)
    return value


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def setting(
    default: Any,
    kind: Kind,
    doc: str,
    *,
    key: str | None = None,
    table: str | None = None,
) -> Any:
    """A dataclass field that is also a declared :class:`Setting` (see :func:`table_of`):
    ``key`` is its name in the spec when it differs from the attribute, ``table`` the spec
    table it belongs to when the dataclass gathers several."""
    import dataclasses

    meta = {"hera_setting": (kind, doc, key, table)}
    if isinstance(default, (dict, list)):
        factory = dict if isinstance(default, dict) else list
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def table_of(cls: type, title: str, table: str | None = None, exclude: Iterable[str] = ()) -> Table:
    """The :class:`Table` of the fields of dataclass ``cls`` declared with :func:`setting`
    (only those of spec table ``table`` when given), in declaration order."""
    import dataclasses

    skip = set(exclude)
    out = []
    for f in dataclasses.fields(cls):
        meta = f.metadata.get("hera_setting")
        if meta is None or f.name in skip:
            continue
        kind, doc, key, tbl = meta
        if table is not None and tbl != table:
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = REQUIRED
        out.append(Setting(key or f.name, kind, default, doc, attr=f.name if key else None))
    return Table(title, out)
