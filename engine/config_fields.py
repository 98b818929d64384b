"""The value types a fit config field is declared with, read back in words, and a ``--set`` string as a value.

``FitConfig`` (engine/config.py) annotates each field with one of the types below; pydantic validates a value
against it, for ``--set`` and for a run's config.json alike. The types are strict, so a value is taken only as
what it is: a bool is no number and a string no count (``--set`` text becomes a value first,
``parse_set_value``), numbers are finite and ints at most ``MAX_INT``. ``Valid`` reads a declaration's range back
in the words the one-line messages and ``--help-config`` use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, get_args, get_origin

from pydantic import AfterValidator, BeforeValidator, Field, TypeAdapter, ValidationError
from pydantic.fields import FieldInfo

from .errors import InputError

#: The largest int a field may take: torch sizes and generator seeds are 64-bit, and nothing a fit counts
#: (steps, pixels, layers) comes near it.
MAX_INT = 2**31 - 1


def whole_number(value: Any) -> Any:
    """A whole finite float as the int it is (JSON and ``--set 1e3`` write counts that way); else ``value``."""
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return int(value)
    return value


def _one_line(value: str) -> str:
    if not value.strip() or "\n" in value:
        raise ValueError("not one line of text")
    return value


# ints at most MAX_INT: ``Valid`` says that bound only to a value beyond it
Int = Annotated[int, BeforeValidator(whole_number), Field(strict=True, le=MAX_INT)]
Float = Annotated[float, Field(strict=True, allow_inf_nan=False)]
#: An int >= 1: a size, or a count of steps, pixels, samples, levels.
Count = Annotated[Int, Field(ge=1)]
NonNegativeInt = Annotated[Int, Field(ge=0)]
Positive = Annotated[Float, Field(gt=0)]
NonNegative = Annotated[Float, Field(ge=0)]
#: A share of something: 0..1.
Share = Annotated[Float, Field(ge=0, le=1)]
#: A factor that shrinks: above 0, at most 1.
Ratio = Annotated[Float, Field(gt=0, le=1)]
Flag = Annotated[bool, Field(strict=True)]
#: Free text: one line, not blank.
OneLine = Annotated[str, Field(strict=True), AfterValidator(_one_line)]


def kind_of(info: FieldInfo) -> str:
    """A declared field's type as a word: ``int``, ``float``, ``bool`` or ``str`` (a field of choices is a ``str``)."""
    kind = info.annotation
    return "str" if get_origin(kind) is Literal else getattr(kind, "__name__", str(kind))


@dataclass(frozen=True)
class Valid:
    """A field's valid values as its declaration states them: a number in [``low``, ``high``] (``above``: strictly
    above ``low``; None: no bound; numbers are always finite and ints at most ``MAX_INT``), or one of ``choices``
    (a str field). bool fields take true or false, str fields without choices any one line of text."""

    low: float | None = None
    high: float | None = None
    above: bool = False
    choices: tuple[str, ...] = ()
    declared: FieldInfo | None = field(default=None, compare=False, repr=False)
    """The declaration this was read from (``accepts`` validates against it)."""

    @classmethod
    def of(cls, info: FieldInfo) -> Valid:
        """The range declared by ``info`` (its annotation's bounds and ``Literal`` choices)."""
        bounds: dict[str, Any] = {}
        for rule in info.metadata:
            if getattr(rule, "ge", None) is not None:
                bounds["low"] = rule.ge
            elif getattr(rule, "gt", None) is not None:
                bounds.update(low=rule.gt, above=True)
            elif getattr(rule, "le", None) is not None and not (info.annotation is int and rule.le == MAX_INT):
                bounds["high"] = rule.le
        choices = get_args(info.annotation) if get_origin(info.annotation) is Literal else ()
        return cls(choices=choices, declared=info, **bounds)

    def accepts(self, value: Any) -> bool:
        """Whether the declaration takes ``value`` as it is."""
        if self.declared is None:
            return True
        kind, rules = self.declared.annotation, self.declared.metadata
        declared: Any = Annotated[(kind, *rules)] if rules else kind
        try:
            TypeAdapter(declared).validate_python(value)
        except ValidationError:
            return False
        return True

    def describe(self, kind: str) -> str:
        """The valid values in words: ``an int >= 1``, ``a number in 0..1``, ``one of fast, paper``."""
        if kind == "bool":
            return "true or false"
        if kind == "str":
            return f"one of {', '.join(self.choices)}" if self.choices else "one line of text"
        noun = "an int" if kind == "int" else "a finite number"
        low = None if self.low is None else _number(self.low, kind)
        high = None if self.high is None else _number(self.high, kind)
        if low is not None and high is not None and not self.above:
            return f"{noun} in {low}..{high}"
        bounds = [f"{'>' if self.above else '>='} {low}"] if low is not None else []
        bounds += [f"<= {high}"] if high is not None else []
        return f"{noun} {' and '.join(bounds)}" if bounds else noun


def _number(value: float, kind: str) -> str:
    return str(int(value)) if kind == "int" or float(value).is_integer() else repr(value)


def parse_set_value(kind: str, raw: str, key: str) -> Any:
    """A ``--set`` string as a value of ``kind``; a one-line error when it is not one."""
    try:
        if kind == "bool":
            low = raw.lower()
            if low in ("1", "true", "yes", "on"):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError(raw)
        if kind == "int":
            value = float(raw)
            if not value.is_integer():
                raise ValueError(raw)
            return int(value)
        if kind == "float":
            return float(raw)
    except (ValueError, OverflowError):
        article = "an" if kind[:1] in "aeiou" else "a"
        raise InputError(None, f"--set {key}={raw}: not a valid {kind}", f"give {key} {article} {kind} value") from None
    return raw


__all__ = [
    "MAX_INT",
    "Count",
    "Flag",
    "Float",
    "Int",
    "NonNegative",
    "NonNegativeInt",
    "OneLine",
    "Positive",
    "Ratio",
    "Share",
    "Valid",
    "kind_of",
    "parse_set_value",
    "whole_number",
]
