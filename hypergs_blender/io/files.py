"""Writing files safely, for every writer (.hgs, .npz, USD, images, reports, weights).

An output is written under a temporary name in its own folder and renamed onto its name
(`os.replace`) only once it is complete: a failed, cancelled or interrupted write (disk full, Ctrl-C,
SIGTERM) leaves the previous file as it was and nothing under the final name. Renaming replaces a
symbolic link at the output's name instead of writing through it, so a link can never lead a write
onto another file. `check_output` refuses, before any work starts, outputs that could not be written
or would destroy an input: a wrong suffix, a missing or unwritable folder, a folder where a file is
wanted, the same file as an input (also through links).

A process killed outright (SIGKILL, a crash, the machine's power) cannot remove its temporary file:
the name carries the host and process id (`.clip.hgs.HOST-PID-RANDOM.part.hgs`), and the next streamed
write of the same output (a clip: minutes of work, a file of any size) removes those of processes of this
host that no longer run (`_remove_stale`; not for every write: it lists the folder, which may hold a
frame sequence). On Windows, where no process id is checked here, they stay until removed by hand.
"""
from __future__ import annotations

import glob
import os
import re
import secrets
import shutil
import socket
from pathlib import Path

from ..errors import HyperGSError
from ..limits import byte_text

_pending: set[Path] = set()  # temporary files not yet committed or discarded
_HOST = re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname()) or "host"


def check_output(path, suffixes=(), inputs=()) -> Path:
    """Raises HyperGSError unless `path` can be written as a new or replaced file: its suffix is one of
    `suffixes` (any when empty), its folder exists and is writable, it is not a folder and not the same
    file as any of `inputs`."""
    path = _path(path)
    if suffixes and path.suffix.lower() not in suffixes:
        raise HyperGSError(f"{path}: the output must end in {', '.join(suffixes)}")
    if path.is_dir():
        raise HyperGSError(f"{path}: is a folder, not a file")
    return _check_target(path, path.parent, inputs)


def check_output_folder(path, inputs=()) -> Path:
    """Like check_output for a folder of outputs: it exists or its parent does (it is then created on
    the first write), it is writable and it is not one of `inputs`."""
    path = _path(path)
    if path.exists() and not path.is_dir():
        raise HyperGSError(f"{path}: is a file, not a folder")
    return _check_target(path, path if path.is_dir() else path.parent, inputs)


def check_free_space(path, needed: float, what: str) -> None:
    """Raises HyperGSError, before the work starts, when the folder of `path` has less than `needed` bytes
    free for `what`: a full disk later would fail as cleanly (no file left) but after the work was spent.
    Where the free space cannot be read, the write itself will say."""
    path = _path(path)
    try:
        free = shutil.disk_usage(path.parent).free
    except OSError:
        return
    if free < needed:
        raise HyperGSError(f"{path}: {what} needs about {byte_text(needed)} free in {path.parent}, which has "
                           f"{byte_text(free)}")


def _check_target(path: Path, folder: Path, inputs) -> Path:
    """What check_output and check_output_folder share: `folder` (where `path` is written) exists and is
    writable, and `path` is none of `inputs`."""
    if not folder.is_dir():
        raise HyperGSError(f"{path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise HyperGSError(f"{path}: the folder {folder} is not writable")
    for source in inputs:
        if same_file(path, source):
            raise HyperGSError(f"{path}: is the input {source}; choose another output")
    return path


def _path(path) -> Path:
    if "\0" in str(path):
        raise HyperGSError(f"{str(path)!r}: a file name cannot hold a NUL character")
    return Path(path)


def same_file(a, b) -> bool:
    """True when a and b name one existing file or folder (following links)."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


class AtomicOutput:
    """The file `path`, written under a temporary name beside it (same suffix, so libraries that pick
    a format by suffix work) and renamed into place by `commit`.

        with AtomicOutput(path) as temp:      # a path: write it whole (np.savez, an image, USD)
            write(temp)                       # committed at the end of the block, discarded on error

        out = AtomicOutput(path, streamed=True)   # out.open() is the temporary file; also removes
        ...; out.commit()  (or out.discard())     # what killed writers of `path` left (_remove_stale)

    OSError while writing or renaming becomes HyperGSError naming `path` (disk full, read-only
    folder). The block should only write: any OSError in it is reported as a write error."""

    def __init__(self, path, inputs=(), streamed: bool = False):
        self.path = check_output(path, inputs=inputs)
        self.file = None
        if streamed:
            _remove_stale(self.path)
        for _ in range(100):
            self.temp = self.path.with_name(f".{self.path.name}.{_HOST}-{os.getpid()}-{secrets.token_hex(4)}"
                                            f".part{self.path.suffix}")
            try:
                os.close(os.open(self.temp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
                break
            except FileExistsError:
                continue
            except OSError as e:
                raise HyperGSError(f"{self.path}: cannot write ({e.strerror})") from None
        _pending.add(self.temp)

    def open(self):
        """The temporary file, opened for writing (binary)."""
        try:
            self.file = open(self.temp, "wb")
        except OSError as e:
            self.discard()
            raise HyperGSError(f"{self.path}: cannot write ({e.strerror})") from None
        return self.file

    def commit(self) -> None:
        """Close the temporary file and rename it onto the output (raises HyperGSError on failure,
        after removing it)."""
        try:
            if self.file is not None:
                self.file.close()
                self.file = None
            os.replace(self.temp, self.path)
        except OSError as e:
            self.discard()
            raise HyperGSError(f"{self.path}: cannot write ({e.strerror or e})") from None
        _pending.discard(self.temp)

    def discard(self) -> None:
        """Remove the temporary file; the output stays as it was. Never raises for a failed close (a
        full disk fails the flush too), so the error that caused the discard is the one reported."""
        if self.file is not None:
            try:
                self.file.close()
            except OSError:
                pass
            self.file = None
        try:
            self.temp.unlink()
        except FileNotFoundError:
            pass
        _pending.discard(self.temp)

    def __enter__(self) -> Path:
        return self.temp

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
            return
        self.discard()
        if issubclass(exc_type, OSError):
            raise HyperGSError(f"{self.path}: cannot write ({exc.strerror or exc})") from None


class StreamingWriter:
    """Mixin of the streaming writers (.hgs, USD): `close()` finishes the file and moves it into place,
    `abort()` drops it (the file at the path stays as it was); as a context manager, an exception
    inside `with` aborts."""

    def close(self) -> None:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _process_runs(pid: int) -> bool:
    """Whether process `pid` of this host runs (True where that cannot be told: Windows, whose
    os.kill would terminate it)."""
    if os.name == "nt":
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


def _remove_stale(path: Path) -> None:
    """Remove the temporary files of `path` left by killed processes of this host (see the module's
    docstring); those of running processes and of other hosts (a shared folder) stay."""
    prefix, suffix = f".{path.name}.", f".part{path.suffix}"
    for temp in path.parent.glob(glob.escape(prefix) + "*" + glob.escape(suffix)):
        owner = temp.name[len(prefix):-len(suffix)].rsplit("-", 2)
        if len(owner) == 3 and owner[0] == _HOST and owner[1].isdigit() and not _process_runs(int(owner[1])):
            # with the temporary files of its own that the same process wrote (EncodePlan.write_hgs streams its
            # float16 frames into one under the output's temporary name)
            nested = path.parent.glob(glob.escape(f".{temp.name}.") + "*" + glob.escape(suffix))
            for leftover in [temp, *nested]:
                try:
                    leftover.unlink()
                except OSError:
                    pass


def discard_pending() -> None:
    """Remove every temporary file not yet committed (the command line calls this on any exit)."""
    for temp in list(_pending):
        try:
            temp.unlink()
        except OSError:
            pass
        _pending.discard(temp)


def make_folders(folder) -> list[Path]:
    """Make `folder` and the folders above it that are missing; returns those made, outermost first
    (for remove_folders). Raises HyperGSError naming the folder that cannot be made."""
    folder = _path(folder)
    missing = []
    while not folder.is_dir() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    made = []
    for path in reversed(missing):
        try:
            path.mkdir()
        except FileExistsError:
            continue  # made meanwhile (by another writer): not ours
        except OSError as e:
            remove_folders(made)
            raise HyperGSError(f"{path}: cannot make the folder ({e.strerror})") from None
        made.append(path)
    return made


def remove_folders(folders) -> None:
    """Remove folders made by make_folders, innermost first, where they are empty (another file may have
    gone there meanwhile: then it and the folders above it stay)."""
    for path in reversed(list(folders)):
        try:
            path.rmdir()
        except OSError:
            return


def write_bytes(path, data: bytes, inputs=()) -> None:
    """Write a small file whole, atomically."""
    with AtomicOutput(path, inputs) as temp:
        temp.write_bytes(data)
