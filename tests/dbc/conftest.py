import os
from collections.abc import Iterator, Mapping
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


class _Corpus(Mapping):
    """The corpus DBCs (``*/*.dbc``, sorted) -> each file as `dbc.errors.load_database` reads it,
    as the commands load a file: its cantools Database, or the DbcLoadError that refuses it. A
    file is parsed the first time a test asks for it, then kept."""

    def __init__(self, files: list[Path]) -> None:
        self._files = files
        self._read: dict[Path, object] = {}

    def __getitem__(self, path: Path) -> object:
        from dbc.errors import DbcLoadError, load_database

        if path not in self._files:
            raise KeyError(path)
        if path not in self._read:
            try:
                self._read[path] = load_database(path)
            except DbcLoadError as exc:
                self._read[path] = exc
        return self._read[path]

    def __iter__(self) -> Iterator[Path]:
        return iter(self._files)

    def __len__(self) -> int:
        return len(self._files)


@pytest.fixture(scope="session")
def corpus_databases() -> _Corpus:
    """The corpus read once for the whole folder (parsing it is the dearest part of its tests):
    the tests share the databases, read them and never change them."""
    return _Corpus(sorted(CORPUS.glob("*/*.dbc")) if CORPUS.is_dir() else [])


@pytest.fixture
def read_once(monkeypatch, corpus_databases):
    """`canstack scenario from-dbc` and `canstack restbus` read a corpus file with `load_database`
    (strict), as `corpus_databases` read it once for tests/dbc: the commands are handed that
    reading (the Database, or the DbcLoadError raised again) instead of parsing the file once
    more. Any other call (a file outside the corpus, strict=False) goes to the real function."""
    from dbc import cli, scenario_cli
    from dbc.errors import DbcLoadError, load_database

    def read_before(path, *, strict=True):
        got = corpus_databases.get(Path(path)) if strict else None
        if got is None:
            return load_database(path, strict=strict)
        if isinstance(got, DbcLoadError):
            raise got
        return got

    for module in (scenario_cli, cli):
        assert module.load_database is load_database  # what the commands call is what is read here
        monkeypatch.setattr(module, "load_database", read_before)
