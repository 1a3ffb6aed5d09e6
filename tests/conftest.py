"""Test settings: on CI (``CI`` set), hypothesis draws the same examples every run, so a
landing never depends on a lucky draw; locally it explores new ones each run."""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
