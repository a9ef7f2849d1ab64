import os
from pathlib import Path

import pytest

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
# ../shared beside the clone; CANSTACK_SHARED points elsewhere (a worktree one level deeper)
SHARED = Path(os.environ.get("CANSTACK_SHARED") or Path(__file__).resolve().parents[3] / "shared")
CORPUS = SHARED / "corpus" / "dbc"


@pytest.fixture(scope="session")
def sample_db():
    from dbc.errors import load_database

    return load_database(SAMPLE)
