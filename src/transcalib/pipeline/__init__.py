"""The pipeline behind ``calibrate()`` (:mod:`.run`) and its stages: the robot's motion
(:mod:`.motion`), the start (:mod:`.start`), the refinement and re-judging
(:mod:`.stages`), the views left out (:mod:`.views_off`), the result (:mod:`.result`).

``calibrate`` is loaded on first use: the command line needs :mod:`.motion` before it
tracks the images, and :mod:`.run` brings in every stage (half a second of imports,
made while the images are tracked).
"""

from __future__ import annotations


def __getattr__(name: str):
    if name == "calibrate":
        from .run import calibrate

        return calibrate
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
