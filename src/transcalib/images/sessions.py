"""``track_sessions``: several groups of views, one orientation per group (a thin wrapper).

Kept for existing callers: ``track_sessions(images, session_of_view, T=T)`` is
``track(images, T=T, sessions=session_of_view)`` (:func:`transcalib.images.track`), which
tracks each session with the pure-translation geometry and links them across
orientations.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .dispatch import track
from .frames import Tracks

__all__ = ["track_sessions"]


def track_sessions(images, session_of_view, *, T=None, rng=0, **track_options) -> Tracks:
    """Track views taken in several sessions (orientations) and link the sessions.

    Parameters
    ----------
    images : sequence of path or array, or array (n_views, h, w[, 3])
        All views, in the order of the robot poses.
    session_of_view : (n_views,) int or str
        Session label of each view; views with one label share one orientation (each
        session needs 2 or more views here).
    T : (n_views, 3) float, optional
        Robot translations of all views.
    rng : seed or Generator
    **track_options
        Passed to :func:`transcalib.images.track`.

    Returns
    -------
    Tracks
        As :func:`transcalib.images.track` with ``sessions=session_of_view``.
    """
    labels = list(np.asarray(session_of_view).tolist())
    n = len(images)
    if len(labels) != n:
        raise InputError(f"track_sessions: session_of_view has {len(labels)} entries for {n} views; "
                         "give one session label per view")
    small = [f"{s!r} (1 view)" for s in dict.fromkeys(labels) if labels.count(s) < 2]
    if small:
        raise InputError(f"track_sessions: every session needs >= 2 views (pure translations); got {', '.join(small)}")
    return track(images, T=T, sessions=labels, rng=rng, **track_options)
