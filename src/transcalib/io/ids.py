"""Point ids: one numpy array per run, integers when every id is one, else text.

A tracks file names its points with any text. Almost always the ids are integers
(``0, 1, 2, ...``), and handling 10⁶ of them as Python strings costs seconds. So the
readers return the ids as an array: ``int64`` when every id is an integer written as
a plain non-negative decimal (ASCII digits, no leading zero, within int64), else
``str``. An id such as ``007``, ``-3`` or ``1e3`` stays text, and so does every id of a
file that has one such id. Writers, the calibration file, the report and the
summary take either kind and never loop over ids in Python.

View ids follow another rule (:func:`canonical_id`): a view id that is a number names
that number, so ``03``, ``3`` and ``3.0`` are one view, in tracks and pose files alike.
"""

from __future__ import annotations

import numpy as np

__all__ = ["canonical_id", "point_id_array", "integer_ids", "truth_index"]


def canonical_id(text: str) -> str:
    """A view id in its canonical form: stripped, and an integer written plainly
    (``"03"``, ``"3.0"`` and ``" 3"`` are ``"3"``); any other text is kept as it is.

    Every reader of view ids (tracks, poses) compares them by this form.
    """
    text = text.strip()
    try:
        value = float(text)
    except ValueError:
        return text
    return str(int(value)) if value.is_integer() else text


def integer_ids(text):
    """The ids ``text`` as ``int64`` when each is a plain integer, else None.

    Parameters
    ----------
    text : pyarrow string array or chunked array (n,)

    Returns
    -------
    (n,) int64 ndarray, or None
        None when an id is not only ASCII digits (a sign, space, point, letter), has a
        leading zero (``007``) or does not fit int64: ``str(id)`` of the result gives
        ``text`` back.
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    if not pc.all(pc.ascii_is_decimal(text), min_count=0).as_py():
        return None
    if pc.any(pc.not_equal(pc.filter(text, pc.starts_with(text, "0")), "0"), min_count=0).as_py():
        return None
    out, start = np.empty(len(text), dtype=np.int64), 0
    for chunk in text.chunks if isinstance(text, pa.ChunkedArray) else [text]:  # no concatenated copy
        try:
            out[start:start + len(chunk)] = pc.cast(chunk, pa.int64()).to_numpy()
        except pa.ArrowInvalid:  # beyond int64
            return None
        start += len(chunk)
    return out


def point_id_array(ids) -> np.ndarray:
    """Point ids as an array: ``int64`` when every id is a plain integer (text ids: see
    :func:`integer_ids`; an integer array stays integer), else ``str``.

    Parameters
    ----------
    ids : (n,) ndarray (integer or text), pyarrow string array, or any sequence

    Returns
    -------
    (n,) int64 or str ndarray
        An integer array is returned as it is (no copy when already int64).
    """
    import pyarrow as pa

    if isinstance(ids, (pa.Array, pa.ChunkedArray)):
        ints = integer_ids(ids.cast(pa.string()))
        return ints if ints is not None else np.asarray(ids.to_numpy(zero_copy_only=False), dtype=str)
    arr = ids if isinstance(ids, np.ndarray) else np.asarray(list(ids))
    if arr.dtype.kind == "i" or (arr.dtype.kind == "u" and (arr.size == 0 or arr.max() < 2**63)):
        return arr.astype(np.int64, copy=False)
    text = arr.astype(str, copy=False)
    if text.size and not _canonical_integer(str(text[0])):  # the usual text ids: decided by the first
        return text
    ints = _few_integer_ids(text) if text.size <= FEW_IDS else integer_ids(pa.array(text))
    return text if ints is None else ints


#: Up to this many text ids are read as integers in Python (:func:`_few_integer_ids`):
#: a view's ids need no pyarrow.compute (0.04 s to import).
FEW_IDS = 1000


def _few_integer_ids(text: np.ndarray) -> np.ndarray | None:
    """:func:`integer_ids` of a few ids ``(n,) str``, one by one."""
    if not all(_canonical_integer(t) for t in text.tolist()):
        return None
    values = [int(t) for t in text.tolist()]
    return np.array(values, dtype=np.int64) if all(v < 2**63 for v in values) else None


def _canonical_integer(s: str) -> bool:
    """One id: is ``s`` a plain integer (:func:`integer_ids`)?"""
    return s.isascii() and s.isdigit() and (s == "0" or not s.startswith("0"))


def truth_index(point_ids, n_true: int) -> np.ndarray | None:
    """The point ids as indices into the ``n_true`` true points of a simulation, or None.

    A simulated scene names its points ``0 .. n_true - 1``; any other ids (text, negative,
    too large, none) give None.

    Returns
    -------
    (n_points,) int64 ndarray or None
    """
    if point_ids is None or len(point_ids) == 0:
        return None
    ids = point_id_array(point_ids)
    if ids.dtype.kind != "i" or ids.min() < 0 or ids.max() >= n_true:
        return None
    return ids
