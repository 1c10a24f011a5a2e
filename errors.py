"""The one exception type that means "the user gave bad input".

Raise :class:`UserError` with a one-line message that names the file, key or
channel and says what was expected. The CLI prints it as
``nearlight: error: <message>`` and exits with status 2; any other exception is
a bug in nearlight and keeps its traceback.
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
        super().__init__(" ".join(str(message).split()))
