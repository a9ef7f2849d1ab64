"""python-can's own back-to-back interface tests (``test/back2back_test.py`` of its source
distribution) on the ``canstack`` interface: two buses on one simulated bus, tested against each
other exactly as python-can tests its own interfaces.

The file is in python-can's sdist, not in its wheel. Fetch the sdist of the installed version
once with::

    pip download --no-binary :all: --no-deps python-can==VERSION -d ~/.cache/canstack

(or point ``CANSTACK_PYTHON_CAN_SDIST`` at it); without it these tests are skipped, saying so.
The buses are opened with ``fd=True``, so the CAN FD cases run too.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import tarfile
import warnings
from pathlib import Path
from types import ModuleType

import can
import pytest

pytestmark = pytest.mark.wallclock

VERSION = can.__version__
CACHE = Path.home() / ".cache" / "canstack"


def _sdist() -> Path | None:
    given = os.environ.get("CANSTACK_PYTHON_CAN_SDIST")
    if given:
        return Path(given) if Path(given).is_file() else None
    for name in (f"python_can-{VERSION}.tar.gz", f"python-can-{VERSION}.tar.gz"):
        if (CACHE / name).is_file():
            return CACHE / name
    return None


def _load(sdist: Path) -> ModuleType:
    """back2back_test as the module of a package of its own (its ``test`` package would shadow
    Python's), extracted next to the sdist once."""
    root = CACHE / f"python_can-{VERSION}-tests"
    tests = root / "pcan_b2b"
    if not (tests / "back2back_test.py").is_file():
        tests.mkdir(parents=True, exist_ok=True)
        with tarfile.open(sdist) as tar:
            for member in tar.getmembers():
                name = Path(member.name)
                if name.parent.name == "test" and name.name in ("back2back_test.py", "config.py"):
                    data = tar.extractfile(member)
                    assert data is not None
                    (tests / name.name).write_bytes(data.read())
        (tests / "__init__.py").write_text("")
    spec = importlib.util.spec_from_file_location(
        "pcan_b2b", tests / "__init__.py", submodule_search_locations=[str(tests)]
    )
    assert spec is not None and spec.loader is not None
    pkg = importlib.util.module_from_spec(spec)
    sys.modules["pcan_b2b"] = pkg
    spec.loader.exec_module(pkg)
    return importlib.import_module("pcan_b2b.back2back_test")


SDIST = _sdist()
if SDIST is None:
    pytest.skip(
        f"python-can's back-to-back tests are in its sdist: pip download --no-binary :all: --no-deps "
        f"python-can=={VERSION} -d {CACHE}",
        allow_module_level=True,
    )
with warnings.catch_warnings():  # its pytest.mark.timeout needs pytest-timeout, a plugin not used here
    warnings.simplefilter("ignore", pytest.PytestUnknownMarkWarning)
    b2b = _load(SDIST)
b2b.TEST_CAN_FD = True  # the buses are opened with fd=TEST_CAN_FD: the FD cases run


class TestCanstackBackToBack(b2b.Back2BackTestCase):  # type: ignore[name-defined,misc]
    """Two canstack nodes on one in-process bus."""

    INTERFACE_1 = INTERFACE_2 = "canstack"
    CHANNEL_1 = CHANNEL_2 = "back2back"
    TIMEOUT = 2.0  # a loaded machine is slow, not wrong: recv returns as soon as the frame is there

    def setUp(self) -> None:
        if self._testMethodName == "test_timestamp":
            self.skipTest("asserts a 2 s sleep within 250 ms: a timed assertion, not run here")
        if self._testMethodName == "test_send_periodic_duration":
            # each of its three runs ends by waiting period + TIMEOUT for a frame that must not
            # come, so the timeout is most of its cost; a frame sent past the duration (the bug it
            # guards against) would come one period after the last, well within it. Still five
            # times python-can's own 0.1 s: the first frame of a run must arrive within it
            self.TIMEOUT = 0.5
        super().setUp()
