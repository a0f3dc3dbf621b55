"""What the fuzz harnesses share (test_hgs_fuzz.py, test_input_fuzz.py): the small limits they run
under, `outcome`, which reads one input and checks that it either reads or fails with a one-line
HyperGSError, within memory and time caps, and the .hgs header's fields (`set_header_field`).

Memory is measured twice: tracemalloc sees every Python and numpy allocation of one input (its peak
is asserted per input); libraries that allocate in C++ (OpenImageIO, USD) are covered by the process'
peak resident size (ru_maxrss), which the stand-alone runs report and cap with RLIMIT_AS.
"""
from __future__ import annotations

import os
import resource
import struct
import time
import tracemalloc
from contextlib import contextmanager

from hypergs_blender.errors import HyperGSError, LimitError
from hypergs_blender.io.hgs import _HEADER

MAX_PEAK_BYTES = 400 << 20  # per input, Python and numpy allocations (a legal 2^20-Gaussian frame decodes in less)
MAX_SECONDS = 10.0  # per input
# The limits the fuzzing runs under: small, so that every legal input is cheap to read.
LIMITS = {"HYPERGS_LIMIT_BYTES": str(64 << 20), "HYPERGS_LIMIT_PIXELS": str(1 << 20),
          "HYPERGS_LIMIT_SIDE": str(4096), "HYPERGS_LIMIT_FRAMES": str(1 << 16)}

# (name, struct format) of the fixed header fields of a .hgs file, in order
HEADER_FIELDS = [("magic", "8s"), ("version", "H"), ("codec", "H"), ("canvas_w", "I"), ("canvas_h", "I"),
                 ("fps", "d"), ("n", "I"), ("grid_c", "H"), ("grid_r", "H"), ("frames", "I"), ("group", "H"),
                 ("reserved", "H")] + [(f"bits{i}", "B") for i in range(8)] + \
                [(f"transform{i}", "B") for i in range(8)] + [(f"range{i}", "d") for i in range(16)] + \
                [("index_offset", "Q"), ("json_len", "I")]
assert struct.calcsize("<" + "".join(f for _, f in HEADER_FIELDS)) == _HEADER.size


def set_header_field(data: bytearray, name: str, value) -> None:
    """Write a .hgs header field (test_hgs_fuzz.py's mutations, test_hostile_inputs.py's crafted files);
    a value its format cannot hold is wrapped."""
    offset = 0
    for field, fmt in HEADER_FIELDS:
        if field == name:
            try:
                struct.pack_into("<" + fmt, data, offset, value)
            except struct.error:
                struct.pack_into("<" + fmt, data, offset, int(value) % (1 << (8 * struct.calcsize(fmt))))
            return
        offset += struct.calcsize("<" + fmt)
    raise KeyError(name)


@contextmanager
def fuzz_limits():
    """LIMITS set in the environment for the duration (the previous values restored after)."""
    saved = {k: os.environ.get(k) for k in LIMITS}
    os.environ.update(LIMITS)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class Stats:
    """Counts of outcomes and the largest memory and time seen, for the stand-alone reports."""

    def __init__(self):
        self.outcomes: dict[str, int] = {}
        self.by_kind: dict[str, dict[str, int]] = {}
        self.max_peak = 0
        self.max_seconds = 0.0
        self.failures: list[str] = []  # inputs that broke the rules (stand-alone runs go on after them)

    @property
    def count(self) -> int:
        return sum(self.outcomes.values()) + len(self.failures)

    def add(self, kind: str, result: str, peak: int, seconds: float) -> None:
        self.outcomes[result] = self.outcomes.get(result, 0) + 1
        kinds = self.by_kind.setdefault(kind, {})
        kinds[result] = kinds.get(result, 0) + 1
        self.max_peak, self.max_seconds = max(self.max_peak, peak), max(self.max_seconds, seconds)

    def report(self) -> dict:
        return {"inputs": self.count, "outcomes": self.outcomes, "by_kind": self.by_kind, "failures": self.failures,
                "max_traced_peak_mib": round(self.max_peak / 2**20, 1), "max_seconds": round(self.max_seconds, 3),
                "max_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}


def outcome(read, what: str, stats: Stats | None = None, kind: str = "") -> str:
    """Run read() (which reads one input) and classify it: 'ok', 'limit' (LimitError) or 'error' (another
    HyperGSError, whose message must be one line naming something); anything else propagates and fails.
    Asserts the memory and time caps; `what` describes the input in failure messages."""
    tracemalloc.start()
    started = time.perf_counter()
    try:
        read()
        result = "ok"
    except LimitError as e:
        assert "HYPERGS_LIMIT_" in str(e), f"a limit error that does not say how to raise it: {e}"
        result = "limit"
    except HyperGSError as e:
        assert str(e) and "\n" not in str(e).strip(), f"not a one-line message: {e!r}"
        result = "error"
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    seconds = time.perf_counter() - started
    assert peak < MAX_PEAK_BYTES, f"{peak / 2**20:.0f} MiB to read {what}"
    assert seconds < MAX_SECONDS, f"{seconds:.1f} s to read {what}"
    if stats is not None:
        stats.add(kind, result, peak, seconds)
    return result


def cap_address_space(gib: float) -> None:
    """RLIMIT_AS for a stand-alone run: an input that slips past the limits fails loudly (MemoryError)
    instead of taking the machine."""
    limit = int(gib * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
