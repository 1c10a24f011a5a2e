"""The one exception type that means "the user gave bad input", and its one special case.

Raise :class:`UserError` with a one-line message that names the file, key or
channel and says what was expected. The CLI prints it as
``nearlight: error: <message>`` and exits with status 2; any other exception is
a bug in nearlight and keeps its traceback. :class:`MissingExtra` (from
:func:`require_extra`) is a :class:`UserError` for a verb that needs an optional
part that is not installed; the CLI prints it as ``nearlight <verb>: needs the
renderer: pip install 'nearlight[render]'``.
"""


class UserError(Exception):
    """Bad input from the user: a file, key, channel or value that is wrong.

    Parameters
    ----------
    message : str
        One line naming what is wrong and what was expected, e.g.
        ``"scenes/x.yaml: lamp.position: expected 3 numbers, got 2"``.
    """

    exit_code = 2

    def __init__(self, message: str):
        super().__init__(one_line(message))


def one_line(text: object) -> str:
    """``str(text)`` on one line: every run of white space (newlines and tabs too) one space, none at the ends.

    The one way a message from elsewhere (an exception, a parser) is put into a
    :class:`UserError` line or a result row's ``error`` column.
    """
    return " ".join(str(text).split())


#: The optional parts of nearlight (``pip install 'nearlight[EXTRA]'``): what each gives, and the
#: modules it installs. A plain install has the estimator, the capture format and the evaluation of
#: existing captures; these are imported only inside the functions that need them.
EXTRAS = {
    "render": ("the renderer", ("mitsuba", "drjit")),
    "cluster": ("the cluster", ("dask", "distributed")),
    "rig": ("the rig import (polanalyser, OpenCV, trimesh)", ("polanalyser", "cv2", "trimesh")),  # embreex: x86-64 only, rig/mesh.py says so
}


class MissingExtra(UserError):
    """A verb needs an optional part of nearlight that is not installed.

    The CLI prints it as ``nearlight <verb>: needs the renderer: pip install
    'nearlight[render]'`` and exits with status 2.

    Parameters
    ----------
    extra : str
        A key of :data:`EXTRAS`.
    """

    def __init__(self, extra: str):
        self.extra = extra
        super().__init__(f"needs {EXTRAS[extra][0]}: pip install 'nearlight[{extra}]'")


def require_extra(extra: str) -> None:
    """Raise :class:`MissingExtra` unless every module of ``extra`` can be imported (found, not imported)."""
    import importlib.util

    for module in EXTRAS[extra][1]:
        try:
            found = importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            raise MissingExtra(extra)


def disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` says the file system is full (ENOSPC, EDQUOT; pyarrow and OpenEXR say it in words only)."""
    import errno

    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    return isinstance(exc, (OSError, RuntimeError)) and "no space left on device" in str(exc).lower()


def no_space(path: object) -> UserError:
    """The one line for a full disk while writing ``path``: ``no space left on <path> (...)``."""
    return UserError(f"no space left on {path} (nothing half-written was kept; free some space, then run the "
                     f"same command again)")
