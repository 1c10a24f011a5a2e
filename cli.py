"""The ``nearlight`` command: one verb per pipeline task.

Each stage package (in ``evaluation/``, each folder of it) owns its verbs in a
``cli`` module exposing ``register(subparsers)``, which adds sub-parsers whose ``run`` default is the
function to call with the parsed arguments. Registration imports nothing heavy:
Mitsuba is imported only when a verb that renders runs.

A :class:`~nearlight.errors.UserError` anywhere becomes one line on stderr and
exit status 2; argparse's own usage errors also exit with 2. A verb that needs
an extra that is not installed (:class:`~nearlight.errors.MissingExtra`) says
which, in one line: ``nearlight render: needs the renderer: pip install
'nearlight[render]'``, exit status 2.

Every verb writes its result on stdout and nothing else there: the answer it
computed (``estimate``'s line, ``compare``'s checks), then the path of each
file or folder it wrote, one a line. Progress bars, status lines, notes,
warnings and errors go to stderr (docs/cli.md).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from collections.abc import Iterator, Sequence

from . import __version__
from .errors import MissingExtra, UserError, disk_full, no_space
from .estimator import cli as estimator_cli
from .evaluation.engine import cli as engine_cli
from .evaluation.gsa import cli as gsa_cli
from .evaluation.paper import cli as paper_cli
from .evaluation.site import cli as site_cli
from .evaluation.suites import cli as suites_cli
from .evaluation.views import cli as views_cli
from .generator import cli as generator_cli
from .rig import cli as rig_cli

#: Modules whose ``register(subparsers)`` adds verbs, in help order. Importing
#: them imports nothing heavy: Mitsuba is imported only when a verb that renders runs.
VERB_MODULES = (paper_cli, generator_cli, rig_cli, estimator_cli, engine_cli, views_cli, gsa_cli, suites_cli,
                site_cli)


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every stage's verbs registered."""
    parser = argparse.ArgumentParser(
        prog="nearlight",
        description="Benchmark near point-light position and specular reflectance estimation "
        "from polarization images.",
    )
    parser.add_argument("--version", action="version", version=f"nearlight {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    for module in VERB_MODULES:
        module.register(sub)
    return parser


class Terminated(BaseException):
    """Raised in the main thread when the process gets SIGTERM, so that every
    ``finally`` and ``with`` block runs (scratch folders, partial files and
    worker processes are cleaned up) before the command exits with 143."""


@contextlib.contextmanager
def _sigterm_unwinds() -> Iterator[None]:
    """While a verb runs, SIGTERM raises :class:`Terminated` (default Python dies without cleaning up)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _check_render_settings() -> None:
    """The renderer's environment variables, checked before any verb does work (a UserError names the bad one)."""
    from .generator.jit_target import planned_target
    from .generator.llvm import planned_variant

    planned_variant()
    planned_target()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``nearlight`` command; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        with _sigterm_unwinds():
            _check_render_settings()
            return int(args.run(args) or 0)
    except MissingExtra as exc:
        print(f"nearlight {args.verb}: {exc}", file=sys.stderr)
        return exc.exit_code
    except UserError as exc:
        print(f"nearlight: error: {exc}", file=sys.stderr)
        return UserError.exit_code
    except OSError as exc:  # a full disk where no writer named the file: still one line, not a traceback
        if not disk_full(exc):
            raise
        print(f"nearlight: error: {no_space(exc.filename or 'the output file system')}", file=sys.stderr)
        return UserError.exit_code
    except KeyboardInterrupt:
        print("nearlight: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("nearlight: terminated", file=sys.stderr)
        return 143
