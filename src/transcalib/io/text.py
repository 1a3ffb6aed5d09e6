"""Large text outputs, fast: numbers formatted by Arrow, chunks formatted on threads.

The writers of ``points.csv`` and the COLMAP model turn millions of numbers into text.
Arrow's compute kernels do it without a Python loop per number (and release the GIL),
so :func:`write_in_order` formats chunks of lines on :data:`THREADS` threads while it
writes the finished chunks, in order. Integers are formatted far faster than floats:
:func:`decimal_text` with ``decimals`` formats a float as a rounded integer and a point.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

__all__ = ["CHUNK", "chunks", "integer_text", "decimal_text", "prefixed", "join", "concatenated", "write_in_order"]

#: Threads formatting text (the machines we aim at have two cores).
THREADS = 2
#: Rows formatted at a time: bounds the memory of a writer at any number of points;
#: small enough for a chunk's arrays to stay in the caches (200 000 was 30 % slower).
CHUNK = 50_000


def chunks(n: int, size: int | None = None):
    """Slices ``[a, a + size)`` covering ``range(n)`` (default size :data:`CHUNK`)."""
    size = size or CHUNK
    return (slice(a, min(a + size, n)) for a in range(0, n, size))


def integer_text(values: np.ndarray, mask: np.ndarray | None = None):
    """Arrow strings of integers ``values (n,)``; null where ``mask`` is True."""
    import pyarrow as pa

    return pa.array(values, mask=mask).cast(pa.string())


def decimal_text(x: np.ndarray, decimals: int | None = None):
    """Arrow strings of floats ``x (n,)``, null where ``x`` is not finite: by default
    the shortest text that reads back as exactly ``x``.

    Parameters
    ----------
    x : (n,) float
    decimals : int >= 1, optional
        Round to this many digits after the point instead, all written (``12.500000``):
        the integer ``round(x * 10**decimals)`` with a point put in, about twice as
        fast (an ``x`` beyond 2**62 / 10**decimals falls back to the exact form).
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    x = np.asarray(x, dtype=float)
    finite = np.isfinite(x)
    mask = None if finite.all() else ~finite
    if decimals is None:
        return pa.array(x, mask=mask).cast(pa.string())
    q = np.round(x * 10.0**decimals)
    if mask is not None:
        q[mask] = 0.0
    size = np.abs(q)
    if size.max(initial=0.0) >= 2.0**62:  # not an int64: the general form
        return decimal_text(x)
    digits = pc.ascii_lpad(integer_text(size.astype(np.int64), mask), decimals + 1, "0")  # "5" -> "0000005"
    text = prefixed(digits, ".", at=-decimals)
    negative = q < 0
    return pc.if_else(pa.array(negative), prefixed(text, "-"), text) if negative.any() else text


def prefixed(strings, prefix: str, at: int = 0):
    """``prefix`` put into each of the ASCII Arrow ``strings`` before character ``at``
    (negative: from the end); nulls stay null. Cheaper than :func:`join`."""
    import pyarrow.compute as pc

    return pc.binary_replace_slice(strings, start=at, stop=at, replacement=prefix)


def join(columns, sep: str = " "):
    """Row-wise join of Arrow string columns (or strings, repeated on every row) with
    ``sep``; null cells are skipped."""
    import pyarrow.compute as pc

    return pc.binary_join_element_wise(*columns, sep, null_handling="skip")


def concatenated(strings, sep: str, end: str = ""):
    """The strings of an Arrow array joined by ``sep``, then ``end``, as one buffer (no
    Python str); nothing at all when there are no strings."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if not len(strings):
        return b""
    joined = pc.binary_join(pa.ListArray.from_arrays(pa.array([0, len(strings)], pa.int32()), strings), sep)
    if end:
        joined = pc.binary_join_element_wise(joined, end, "")
    return joined[0].as_buffer()


def write_in_order(fh, pieces, threads: int = THREADS) -> None:
    """Write ``pieces`` to the binary file ``fh``, in order.

    A piece is bytes-like (written as it is) or a callable returning bytes-like, run on
    a pool of ``threads`` threads at most ``2 * threads`` pieces ahead of the writing.
    ``pieces`` may be a generator: it is consumed as the writing proceeds.
    """
    with ThreadPoolExecutor(threads) as pool:
        ahead = deque()
        for piece in pieces:
            ahead.append(pool.submit(piece) if callable(piece) else piece)
            while len(ahead) > 2 * threads:
                _write(fh, ahead.popleft())
        while ahead:
            _write(fh, ahead.popleft())


def _write(fh, piece) -> None:
    fh.write(piece.result() if isinstance(piece, Future) else piece)
