"""Constructor-argument specs and validation shared by every environment.

Every keyword argument of an environment is declared once as a :class:`Param` with its default, its
documentation and a validator. The validator both checks a value (raising ``ValueError`` that names
the argument and what is allowed) and describes the allowed range for the generated docs. Hypothesis
property tests draw random valid values from the validators' ``fuzz_range``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from numbers import Integral
from numbers import Real as _RealNumber
from typing import Any


class Validator:
    """Checks one argument and describes what is allowed."""

    def __call__(self, name: str, value: Any) -> Any:  # pragma: no cover - interface
        raise NotImplementedError

    def describe(self) -> str:  # pragma: no cover - interface
        raise NotImplementedError

    def _fail(self, name: str, value: Any) -> None:
        raise ValueError(f"argument '{name}' must be {self.describe()}, got {value!r}")


@dataclass(frozen=True)
class Int(Validator):
    lo: int | None = None
    hi: int | None = None
    #: range that property tests draw from (cheap but representative values)
    fuzz: tuple[int, int] | None = None

    def __call__(self, name: str, value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, Integral):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                self._fail(name, value)
        number = int(value)
        if (self.lo is not None and number < self.lo) or (self.hi is not None and number > self.hi):
            self._fail(name, number)
        return number

    def describe(self) -> str:
        if self.lo is not None and self.hi is not None:
            return f"an integer in [{self.lo}, {self.hi}]"
        if self.lo is not None:
            return f"an integer ≥ {self.lo}"
        if self.hi is not None:
            return f"an integer ≤ {self.hi}"
        return "an integer"


@dataclass(frozen=True)
class Real(Validator):
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    allow_inf: bool = False
    fuzz: tuple[float, float] | None = None

    def __call__(self, name: str, value: Any) -> float:
        if isinstance(value, str) and value.strip().lower() in ("inf", "+inf", "infinity") and self.allow_inf:
            value = math.inf
        if isinstance(value, bool) or not isinstance(value, _RealNumber):
            self._fail(name, value)
        number = float(value)
        if math.isnan(number) or (math.isinf(number) and not (self.allow_inf and number > 0)):
            self._fail(name, number)
        if self.lo is not None and (number < self.lo or (self.lo_open and number == self.lo)):
            self._fail(name, number)
        if (
            self.hi is not None
            and not math.isinf(number)
            and (number > self.hi or (self.hi_open and number == self.hi))
        ):
            self._fail(name, number)
        return number

    def describe(self) -> str:
        lo = "-inf" if self.lo is None else f"{self.lo:g}"
        hi = "inf" if self.hi is None else f"{self.hi:g}"
        left = "(" if (self.lo is None or self.lo_open) else "["
        right = "]" if (self.hi is not None and not self.hi_open) or (self.hi is None and self.allow_inf) else ")"
        text = f"a number in {left}{lo}, {hi}{right}"
        if self.allow_inf and self.hi is not None:
            text += " or inf"
        return text


@dataclass(frozen=True)
class Choice(Validator):
    options: tuple[Any, ...]

    def __call__(self, name: str, value: Any) -> Any:
        if isinstance(value, bool) or value not in self.options:
            raise ValueError(f"argument '{name}' must be one of {', '.join(map(repr, self.options))}; got {value!r}")
        return value

    def describe(self) -> str:
        return "one of " + ", ".join(f"`{o}`" for o in self.options)


@dataclass(frozen=True)
class Bool(Validator):
    def __call__(self, name: str, value: Any) -> bool:
        if not isinstance(value, bool):
            self._fail(name, value)
        return bool(value)

    def describe(self) -> str:
        return "true or false"


@dataclass(frozen=True)
class Optional(Validator):
    """``None`` (the feature is off) or a value the inner validator accepts."""

    inner: Validator

    def __call__(self, name: str, value: Any) -> Any:
        return None if value is None else self.inner(name, value)

    def describe(self) -> str:
        return f"null or {self.inner.describe()}"


@dataclass(frozen=True)
class ListOf(Validator):
    """A non-empty list of distinct items, each checked by ``item``."""

    item: Validator
    min_len: int = 1
    unique: bool = True

    def __call__(self, name: str, value: Any) -> tuple:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise ValueError(f"argument '{name}' must be {self.describe()}, got {value!r}")
        items = tuple(self.item(name, v) for v in value)
        if len(items) < self.min_len:
            raise ValueError(f"argument '{name}' must be {self.describe()}, got {value!r}")
        if self.unique and len(set(items)) != len(items):
            raise ValueError(f"argument '{name}' must not repeat items, got {value!r}")
        return items

    def describe(self) -> str:
        return f"a list of at least {self.min_len} distinct items, each {self.item.describe()}"


class _Anything(Validator):
    def __call__(self, name: str, value: Any) -> Any:
        return value

    def describe(self) -> str:
        return "any value"


_ANY = _Anything()


@dataclass(frozen=True)
class Param:
    """One constructor argument: its default, what it means and what is allowed."""

    default: Any
    doc: str
    check: Validator = field(default_factory=lambda: _ANY)

    def allowed(self) -> str:
        return self.check.describe()


class Config(dict):
    """Validated arguments, readable as attributes (``cfg.n_robots``) and as a dict."""

    def __getattr__(self, key: str) -> Any:
        try:
            return self[key]
        except KeyError as exc:
            raise AttributeError(key) from exc


def validate_config(params: dict[str, Param], kwargs: dict[str, Any], owner: str = "environment") -> Config:
    """Check ``kwargs`` against ``params``; unknown names raise ``ValueError`` listing the valid ones."""
    unknown = sorted(set(kwargs) - set(params))
    if unknown:
        raise ValueError(
            f"unknown argument(s) {', '.join(map(repr, unknown))} for {owner}; "
            f"valid arguments are: {', '.join(sorted(params))}"
        )
    cfg = Config()
    for name, spec in params.items():
        value = kwargs.get(name, spec.default)
        cfg[name] = spec.check(name, value)
    return cfg
