from pathlib import Path

import pytest

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
SHARED = Path(__file__).resolve().parents[3] / "shared"
CORPUS = SHARED / "corpus" / "dbc"


@pytest.fixture(scope="session")
def sample_db():
    from dbc.errors import load_database

    return load_database(SAMPLE)
