"""`hypergs` command line. Each module in COMMAND_MODULES adds its own subcommands with
`add_commands(subparsers)`; modules are imported only when the CLI starts.

Whatever goes wrong ends in one line on stderr, `hypergs <command>: error: ...`, and a non-zero exit
status, never a traceback: a bad argument (exit 2, options.py), bad input or an unwritable output
(HyperGSError, exit 1), an unexpected OSError such as a full disk (exit 1), Ctrl-C and SIGTERM. Temporary
files of unfinished outputs are removed on every exit (io/files.py).

Ctrl-C and SIGTERM, once the line is printed and the files are cleaned up, end the process by that
signal (on POSIX; a shell reads 130 / 143, a parent process -2 / -15): a shell loop over encodes then
stops at Ctrl-C instead of going on with the next one, and the status no longer depends on whether
CPython itself saw the KeyboardInterrupt leave a nested evaluation (it then re-raises SIGINT at exit
whatever status the command asked for, as it did now and then when Ctrl-C landed in numba's JIT).
"""
from __future__ import annotations

import importlib
import os
import signal
import sys
import threading

from ..errors import HyperGSError, one_line
from ..io import files
from .options import Parser, check_paths, command_parser

COMMAND_MODULES = ["encode", "evaluate", "fit", "train", "data", "clips", "bench", "build"]


# Packages whose Python code runs as callbacks from native code (numba's JIT, through llvmlite's
# ctypes callbacks): an exception raised there is printed and dropped, or leaves the compiler in a
# state that crashed the process (SIGSEGV) now and then.
_NATIVE_CALLBACK_PACKAGES = ("numba", "llvmlite")
_SIGNAL_RETRY_SECONDS = 0.05


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived (raised in the main thread, so that every `with` and `finally` cleans up). A
    KeyboardInterrupt, as Ctrl-C's, so that code which stops on Ctrl-C stops on this too."""


def build_parser() -> Parser:
    parser = Parser(prog="hypergs", description="HyperGS: videos to editable 2D Gaussians in one forward pass.")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__package__}.{name}").add_commands(subparsers)
    return parser


def _in_native_callback(frame) -> bool:
    while frame is not None:
        parts = frame.f_code.co_filename.replace("\\", "/").split("/")
        if any(name in parts for name in _NATIVE_CALLBACK_PACKAGES):
            return True
        frame = frame.f_back
    return False


def _interrupt(signum, frame):
    """SIGINT / SIGTERM: raise in the main thread, but never inside the JIT (numba compiling or
    loading a kernel from its cache): there the signal is raised again a moment later, until it
    lands in code that can unwind."""
    if _in_native_callback(frame):
        timer = threading.Timer(_SIGNAL_RETRY_SECONDS, signal.raise_signal, (signum,))
        timer.daemon = True
        timer.start()
        return
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def main(argv=None) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    command = command_parser(parser, args)
    check_paths(command, args)
    in_main = threading.current_thread() is threading.main_thread()
    handled = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, _interrupt) for s in handled} if in_main else {}
    status = 0
    try:
        args.func(args)
    except BaseException as e:
        failure = _failure(e)
        if failure is None:
            raise  # a bug: its traceback
        status, message = failure
        print(f"{command.prog}: error: {one_line(message)}", file=sys.stderr)
    finally:
        files.discard_pending()
        for s, handler in previous.items():
            signal.signal(s, handler)
    if status > 128 and in_main and os.name == "posix":  # an interruption: 128 + its signal (_failure)
        _end_by_signal(status - 128)
    if status:
        sys.exit(status)


def _end_by_signal(signum: int) -> None:
    """Die of `signum` with its default action, as a Unix tool that caught it should (module docstring)."""
    sys.stdout.flush()
    sys.stderr.flush()
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signum])  # delivered by now unless it was blocked


def _failure(error: BaseException) -> tuple[int, str] | None:
    """(exit status, message) of an error that ends a command with one line; None for the others.
    An interruption counts wherever it arrived: a library may wrap it (numba raises SystemError with
    the KeyboardInterrupt as its cause)."""
    cause = error
    while cause is not None:
        if isinstance(cause, Terminated):
            return 128 + signal.SIGTERM, "terminated"
        if isinstance(cause, KeyboardInterrupt):
            return 128 + signal.SIGINT, "interrupted"
        cause = cause.__cause__ or cause.__context__
    if isinstance(error, HyperGSError):
        return 1, str(error)
    if isinstance(error, MemoryError):
        return 1, "out of memory (lower the sizes, or the limits: see hypergs_blender/limits.py)"
    if isinstance(error, OSError):  # a full disk, a folder made read-only meanwhile, a closed pipe
        return 1, (f"{error.filename}: " if error.filename else "") + (error.strerror or str(error))
    return None
