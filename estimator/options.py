"""Estimator options: declared once, in each method's signature, and checked from that declaration.

A method declares its options as keyword parameters with annotated types;
ranges and choices use the annotated types below (``Annotated`` with pydantic
constraints), e.g. ``threshold: Fraction = 0.05`` or ``loss: Choice(LOSSES) =
"soft_l1"``. A method that passes ``**options`` on to another function says so
with :func:`forwards` and inherits that function's declared options.
:func:`check_options` validates a mapping of options against the declaration
before the method runs (``nearlight estimate --set``, ``estimate(...)``, and
every method of a sweep file when it is loaded): an unknown option, a wrong
type or a value out of range is one :class:`~nearlight.errors.UserError` line
naming the option. Plug-ins (``module:function``) are checked the same way as
far as they declare: unannotated parameters take any value, and a plug-in with
a bare ``**options`` takes any option.
"""

from __future__ import annotations

import inspect
import typing
from collections.abc import Callable, Iterable, Mapping
from typing import Annotated, Any

from pydantic import AfterValidator, Field, TypeAdapter, ValidationError

from ..errors import UserError

#: A finite number > 0 (distances, steps, scales), in the option's units.
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
#: A fraction in (0, 1).
Fraction = Annotated[float, Field(gt=0, lt=1)]
#: A whole number >= 1.
Count = Annotated[int, Field(ge=1)]
#: A whole number >= 0.
CountOrZero = Annotated[int, Field(ge=0)]


def Choice(names: Iterable[str]) -> Any:  # noqa: N802 - reads as a type in signatures
    """The annotated type of an option that names one of ``names`` (a registry's keys)."""
    allowed = tuple(names)

    def one_of(value: str) -> str:
        if value not in allowed:
            raise ValueError(f"expected one of {', '.join(allowed)}")
        return value

    return Annotated[str, AfterValidator(one_of)]


def forwards(target: Callable, *, fixed: Iterable[str] = ()) -> Callable[[Callable], Callable]:
    """Declare that a method passes its ``**options`` on to ``target`` (minus the ``fixed`` ones it sets itself)."""

    def mark(fn: Callable) -> Callable:
        fn.__nearlight_forwards__ = (target, frozenset(fixed))
        return fn

    return mark


def declared_options(fn: Callable) -> tuple[dict[str, tuple[Any, Any]], bool]:
    """The options ``fn`` declares, and whether it takes any other.

    Returns
    -------
    options : dict
        Name -> (annotation or ``inspect.Parameter.empty``, default).
    open_ended : bool
        True when ``fn`` takes ``**options`` that it does not declare as forwarded.
    """
    sig = inspect.signature(fn)
    try:
        hints = typing.get_type_hints(fn, include_extras=True)
    except Exception:  # a plug-in's annotations may not resolve: treat them as undeclared
        hints = {}
    params = list(sig.parameters.values())[1:]  # the first takes the capture
    out = {
        p.name: (hints.get(p.name, inspect.Parameter.empty), p.default)
        for p in params
        if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)
    }
    open_ended = any(p.kind is p.VAR_KEYWORD for p in params)
    forwarded = getattr(fn, "__nearlight_forwards__", None)
    if open_ended and forwarded is not None:
        target, fixed = forwarded
        inner, open_ended = declared_options(target)
        out = {**{k: v for k, v in inner.items() if k not in fixed}, **out}
    return out, open_ended


def check_options(fn: Callable, options: Mapping[str, Any], *, method: str) -> dict[str, Any]:
    """Validate ``options`` against what ``fn`` declares.

    Parameters
    ----------
    fn : callable
        The method, ``fn(capture, **options)``.
    options : mapping
        Option name -> value (already parsed: JSON/YAML values).
    method : str
        The method's name, for messages.

    Returns
    -------
    dict
        The options, values as validated (e.g. an int where a float is declared stays a number).

    Raises
    ------
    UserError
        ``option NAME: ...`` for an option the method does not take, a wrong type or a value out of range.
    """
    declared, open_ended = declared_options(fn)
    out = {}
    for name, value in options.items():
        if name not in declared:
            if open_ended:
                out[name] = value
                continue
            accepted = ", ".join(declared) or "none"
            raise UserError(f"option {name!r}: not accepted by method {method} (it takes: {accepted})")
        annotation, _ = declared[name]
        if annotation is inspect.Parameter.empty:
            out[name] = value
            continue
        try:
            out[name] = TypeAdapter(annotation).validate_python(value, strict=True)
        except ValidationError as exc:
            err = exc.errors()[0]
            raise UserError(f"option {name}: {err['msg']} (got {value!r})") from None
    return out
