class HyperGSError(Exception):
    """A problem with the user's input (a file, an option). Front ends show the message, no traceback."""


def reason(error: BaseException) -> str:
    """A library's exception as one line for our messages: its last non-empty line (the specific one
    in USD's and OpenImageIO's multi-line reports), or its type when it has no readable text."""
    try:
        lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    except Exception:  # pxr's Tf.ErrorException can fail to decode a damaged file's bytes
        lines = []
    return lines[-1] if lines else type(error).__name__


def one_line(text) -> str:
    """Text with its line breaks and runs of spaces made single spaces."""
    return " ".join(str(text).split())


class VideoError(HyperGSError):
    """A video that is missing, unreadable or undecodable; the message names the file."""


class LimitError(HyperGSError):
    """An input or an option past one of the limits of limits.py; the message names the limit and how
    to raise it."""


class Cancelled(HyperGSError):
    """The user cancelled (an encode, a render); nothing was written."""
