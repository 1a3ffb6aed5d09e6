"""Simulated scenes with exact ground truth (:mod:`.simulate`) and the image renderer
(:mod:`.render`), and renders of a robot's views at any flange pose (:mod:`.robot`): data for
tests, benchmarks and examples."""

from . import simulate
from .simulate import Scene, observe, paper_scene, random_scene

__all__ = ["simulate", "Scene", "observe", "paper_scene", "random_scene", "render_scene", "robot_scene"]


def render_scene(*args, **kwargs):
    """Rendered images with exact ground truth: :func:`transcalib.synth.render.render_scene`
    (the renderer loads OpenCV, so it is imported on first use)."""
    from .render import render_scene as _render_scene

    return _render_scene(*args, **kwargs)


def robot_scene(*args, **kwargs):
    """Renders of a robot's views with exact truth, eye-in-hand or eye-to-hand:
    :func:`transcalib.synth.robot.robot_scene` (imported on first use, like the renderer)."""
    from .robot import robot_scene as _robot_scene

    return _robot_scene(*args, **kwargs)
