class HyperGSError(Exception):
    """A problem with the user's input (a file, an option). Front ends show the message, no traceback."""


class VideoError(HyperGSError):
    """A video that is missing, unreadable or undecodable; the message names the file."""
