"""One entry point for every estimator: built-in methods and ``module:function`` plug-ins."""

from __future__ import annotations

import importlib
import inspect
import os
import time
from collections.abc import Callable, Mapping
from typing import Any
from pathlib import Path

from ..capture import Capture, read_capture
from ..errors import UserError, one_line, require_extra
from .distant import distant_estimate
from .full import full_estimate
from .lambertian_plane import lambertian_plane_estimate
from .mirror_spheres import mirror_spheres_estimate
from .options import check_options
from .first_stage import initial_estimate
from .paper import paper_estimate
from .result import Estimate
from .geometry import surface_geometry
from .observation import already_shared, shared_observations
from .sanity import review

#: Built-in methods: ``fn(capture, **options) -> Estimate``.
METHODS: dict[str, Callable[..., Estimate]] = {
    "paper": paper_estimate,
    "paper-init": initial_estimate,
    "full": full_estimate,
    "distant": distant_estimate,
    "lambertian-plane": lambertian_plane_estimate,
    "mirror-spheres": mirror_spheres_estimate,
}
#: A method function with this attribute true sees a capture's calibration targets (every pixel); every other
#: method sees the object's pixels only (:meth:`~nearlight.capture.Capture.of_object`).
USES_TARGETS = "uses_targets"
#: Methods of an extra, by name: (extra, ``module:function``), imported only when asked for.
EXTRA_METHODS = {"render-compare": ("render", "nearlight.rendercompare.method:render_compare_estimate")}


def load_method(spec: str) -> Callable[..., Estimate]:
    """The estimator function for a method name or a ``module:function`` spec.

    Parameters
    ----------
    spec : str
        A key of :data:`METHODS`, or ``"package.module:function"`` naming any
        function with the signature ``fn(capture, **options) -> Estimate``.

    Raises
    ------
    UserError
        Unknown method, module that cannot be imported, or missing function.
    """
    if spec in METHODS:
        return METHODS[spec]
    if spec in EXTRA_METHODS:
        require_extra(EXTRA_METHODS[spec][0])
        spec = EXTRA_METHODS[spec][1]
    module_name, sep, func_name = spec.partition(":")
    if not sep or not module_name or not func_name:
        raise UserError(f"unknown method {spec!r} (expected one of {', '.join([*METHODS, *EXTRA_METHODS])} "
                        "or module:function)")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise UserError(f"method {spec}: cannot import module {module_name!r} ({exc})") from None
    except (Exception, SystemExit) as exc:  # a plug-in's own code failed at import (SyntaxError, sys.exit, ...)
        if module_name.split(".")[0] == "nearlight":  # nearlight's own method (EXTRA_METHODS): a bug, keep it
            raise
        where = f" at {exc.filename}:{exc.lineno}" if isinstance(exc, SyntaxError) else ""
        raise UserError(f"method {spec}: importing module {module_name!r} failed with {type(exc).__name__}{where}: "
                        f"{one_line(exc)[:200]}") from None
    fn = getattr(module, func_name, None)
    if not callable(fn):
        raise UserError(f"method {spec}: module {module_name!r} has no function {func_name!r}")
    return fn


def estimate(capture: Capture | str | os.PathLike, *, method: str = "paper", sanity: bool = True,
             **options) -> Estimate:
    """Estimate the lamp position and specular reflectance of one capture.

    Parameters
    ----------
    capture : Capture or path-like
        A capture, or a capture directory to read.
    method : str, optional
        ``"paper"`` (default), ``"paper-init"``, ``"full"``, ``"distant"``,
        ``"render-compare"`` (:data:`EXTRA_METHODS`) or a plug-in's ``"module:function"``.
    sanity : bool, optional
        Hold the result to the rules of :mod:`nearlight.estimator.sanity`
        (default): one it breaks is returned refused (``status="failed"``, NaN
        numbers, the reason in ``diagnostics["failure"]``). False only for
        studies of a method's inner stages that read their raw numbers
        (:mod:`nearlight.evaluation.paper.fidelity`).
    **options
        Method options (see each method's docstring), e.g. ``t_max=2.0``;
        checked against the method's declaration before it runs
        (:func:`~nearlight.estimator.options.check_options`).

    Returns
    -------
    Estimate
        With ``method`` set to the name asked for. ``timings`` holds seconds
        per stage, summing to the run time (``{"total": …}`` when the method
        reports none; the rules' own time is ``timings["sanity"]``). Check
        ``status`` (or ``ok``) before reading its numbers.

    Raises
    ------
    UserError
        Bad input, unknown method, an option the method does not declare or
        of the wrong type or range, or a plug-in that fails (its exception in
        one line: a plug-in is the user's code).
    """
    return answer_and_verdict(capture, method=method, sanity=sanity, **options)[1]


def answer_and_verdict(capture: Capture | str | os.PathLike, *, method: str = "paper", sanity: bool = True,
                       **options) -> tuple[Estimate, Estimate]:
    """:func:`estimate`, returning also the method's own answer before the rules.

    Returns
    -------
    answer : Estimate
        What the method returned (timings, ``geometry`` diagnostics).
    verdict : Estimate
        ``answer`` held to the rules of :mod:`nearlight.estimator.sanity` (``answer`` itself when it
        passes them, or when ``sanity`` is False): what :func:`estimate` returns. A results file
        (:mod:`nearlight.evaluation.suites.results_file`) keeps the answer, so that a re-score holds it to
        the same rules with the same verdict.
    """
    fn = load_method(method)
    options = check_options(fn, options, method=method)
    if isinstance(capture, (str, os.PathLike, Path)):
        capture = read_capture(capture)
    if not getattr(fn, USES_TARGETS, False):  # the object's pixels only (a capture that says which pixel is which)
        capture = capture.of_object()
    with shared_observations():  # the rules read the observation the method made
        clock = time.perf_counter()
        answer = _run(fn, capture, method, options)
        geometry = already_shared(surface_geometry, capture)
        if geometry is not None:
            answer.diagnostics.setdefault("geometry", geometry.summary)
        if not answer.timings:
            answer.timings["total"] = time.perf_counter() - clock
        verdict = answer
        if sanity and answer.ok:
            clock = time.perf_counter()
            verdict = review(capture, answer, _rules_options(fn, options))
            verdict.timings["sanity"] = time.perf_counter() - clock
    return answer, verdict


def rules_options(method: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """The options the sanity rules hold ``method``'s answers with: its own defaults of the options that shape
    its observation (:func:`observation_defaults`), then ``options``."""
    return _rules_options(load_method(method), options)


def _rules_options(fn: Callable[..., Estimate], options: Mapping[str, Any]) -> dict[str, Any]:
    return {**observation_defaults(fn), **options}


def observation_defaults(fn: Callable[..., Estimate]) -> dict[str, object]:
    """A method's own defaults of the options that shape its observation (``separation``, ``threshold``), so the
    sanity rules see the capture as the method did (``full`` separates by ``projected``, the others by ``fit``)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return {}
    return {k: params[k].default for k in ("separation", "threshold")
            if k in params and params[k].default is not inspect.Parameter.empty}


def _run(fn: Callable[..., Estimate], capture: Capture, method: str, options: dict) -> Estimate:
    """``fn(capture, **options)``, its result checked; a plug-in's failure of any kind is one line naming it."""
    if method in METHODS or method in EXTRA_METHODS:
        result = fn(capture, **options)
    else:
        try:
            result = fn(capture, **options)
        except UserError:
            raise
        except (Exception, SystemExit) as exc:  # sys.exit() in a plug-in is its failure, not nearlight's exit
            raise UserError(
                f"method {method}: failed with {type(exc).__name__}: {one_line(exc)[:200]} "
                "(a plug-in is fn(capture, **options) -> nearlight.estimator.Estimate)"
            ) from None
    if not isinstance(result, Estimate):
        raise UserError(f"method {method}: returned {type(result).__name__}, expected nearlight.estimator.Estimate")
    result.method = method
    return result
