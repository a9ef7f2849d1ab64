"""Test-wide settings: hypothesis without per-example deadlines (a loaded CI machine is slow,
not wrong), and with a fixed seed on CI so a run there is reproducible."""

import os

from hypothesis import settings

settings.register_profile("canstack", deadline=None, derandomize=bool(os.environ.get("CI")))
settings.load_profile("canstack")
