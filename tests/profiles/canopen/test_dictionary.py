"""The object dictionary: EDS loading through canopen's import_od, the checks a device needs,
and the access rules of every write with CiA 301's abort codes."""

import re

import pytest

from profiles.canopen.dictionary import DEFAULT_EDS, EdsError, ObjectStore, load_od
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort


@pytest.fixture
def store():
    return ObjectStore(load_od(None, 5))


def eds_with(tmp_path, edit, name="device.eds"):
    """The default EDS with ``edit(text) -> text`` applied, as a file."""
    p = tmp_path / name
    p.write_text(edit(DEFAULT_EDS.read_text()))
    return p


def drop_section(text, section):
    """Remove ``[section]`` and its sub-index sections ``[sectionsubN]``."""
    return re.sub(rf"^\[{section}(?:sub[0-9A-Fa-f]+)?\]\n(?:(?!\[).*\n)*", "", text, flags=re.M)


def test_default_eds_has_cia_301s_mandatory_objects_and_resolves_nodeid(store):
    for index in (0x1000, 0x1001, 0x1018, 0x1017):
        assert store.has(index, 0) or store.has(index, 1)
    assert store.get(0x1014) == 0x85  # $NODEID+0x80: COB-ID EMCY of node 5
    assert store.get(0x1200, 1) == 0x605 and store.get(0x1200, 2) == 0x585
    assert [store.get(0x1800 + n, 1) for n in range(4)] == [0x185, 0x285, 0x385, 0x485]
    assert [store.get(0x1400 + n, 1) & 0x7FF for n in range(4)] == [0x205, 0x305, 0x405, 0x505]
    assert store.get(0x1403, 1) & 0x8000_0000  # RPDO4 shipped not valid


def test_the_shipped_eds_is_package_data():
    assert DEFAULT_EDS.name == "default.eds" and DEFAULT_EDS.is_file()
    from pathlib import Path

    import tomllib

    py = tomllib.loads((Path(__file__).resolve().parents[3] / "pyproject.toml").read_text())
    assert "*.eds" in py["tool"]["setuptools"]["package-data"]["profiles.canopen"]


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: drop_section(t, "1001"), r"mandatory object 0x1001 \(error register\) is missing"),
        (
            lambda t: drop_section(drop_section(drop_section(t, "1017"), "100C"), "100D"),
            r"neither 0x1017 .* nor 0x100C/0x100D",
        ),
        (
            lambda t: t.replace(
                "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006",
                "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0007",
            ),
            r"0x1017 \(Producer heartbeat time\) must be UNSIGNED16 .*not UNSIGNED32",
        ),
        (lambda t: drop_section(t, "1A01"), r"TPDO2: 0x1801 is defined without 0x1A01"),
        (
            lambda t: t.replace(
                "ParameterName=Temperature\nObjectType=0x7\nDataType=0x0003\nAccessType=rw\nDefaultValue=250",
                "ParameterName=Temperature\nObjectType=0x7\nDataType=0x0003\nAccessType=rw\nDefaultValue=70000",
            ),
            r"0x2003 \(Temperature\): default value 70000 does not fit INTEGER16",
        ),
        (
            lambda t: t + "\n[2999sub1]\nParameterName=orphan\nDataType=0x0005\nAccessType=rw\n",
            r"a sub-index section names an object that is not defined",
        ),
        (lambda t: t.replace("[1018]", "[1018", 1), r"not a valid EDS \(CiA 306 INI syntax\)"),
    ],
)
def test_malformed_eds_names_the_file_and_the_problem(tmp_path, edit, message):
    path = eds_with(tmp_path, edit)
    with pytest.raises(EdsError, match=message) as exc:
        load_od(path, 5)
    assert str(exc.value).startswith(str(path) + ": ")


def test_eds_path_problems(tmp_path):
    with pytest.raises(EdsError, match=r"no such file"):
        load_od(tmp_path / "missing.eds", 1)
    (tmp_path / "od.txt").write_text("x")
    with pytest.raises(EdsError, match=r"an object dictionary is an \.eds or \.dcf file"):
        load_od(tmp_path / "od.txt", 1)
    (tmp_path / "bin.eds").write_bytes(b"\xff\xfe\x00\x81" * 10)
    with pytest.raises(EdsError, match=r"bin\.eds: not"):
        load_od(tmp_path / "bin.eds", 1)


def test_dcf_parameter_values_win_over_defaults(tmp_path):
    path = eds_with(
        tmp_path,
        lambda t: t.replace(
            "ParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=1000",
            "ParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=1000\n"
            "ParameterValue=250",
        ),
        name="device.dcf",
    )
    assert ObjectStore(load_od(path, 3)).get(0x1017) == 250


@pytest.mark.parametrize(
    "index, sub, data, code",
    [
        (0x3000, 0, b"\x00", abort.NO_OBJECT),
        (0x1018, 9, b"\x00\x00\x00\x00", abort.NO_SUBINDEX),
        (0x1000, 0, b"\x00\x00\x00\x00", abort.READ_ONLY),
        (0x1008, 0, b"x", abort.READ_ONLY),  # const
        (0x1017, 0, b"\x01\x02\x03", abort.LENGTH_HIGH),
        (0x1017, 0, b"\x01", abort.LENGTH_LOW),
        (0x2003, 0, (1251).to_bytes(2, "little", signed=True), abort.VALUE_HIGH),  # HighLimit 1250
        (0x2003, 0, (-401).to_bytes(2, "little", signed=True), abort.VALUE_LOW),  # LowLimit -400
    ],
)
def test_sdo_write_refusals_with_cia_301_abort_codes(store, index, sub, data, code):
    with pytest.raises(SdoAbort) as exc:
        store.sdo_write(index, sub, data)
    assert exc.value.code == code


def test_reads_of_write_only_objects_are_refused(store):
    with pytest.raises(SdoAbort) as exc:
        store.sdo_read(0x2203, 0)
    assert exc.value.code == abort.WRITE_ONLY
    assert store.read(0x2203, 0) == b"\x00"  # the device itself may


def test_limits_pass_inside_and_watchers_hear_of_writes(store):
    seen = []
    store.watch(0x2003, 0, lambda i, s: seen.append((i, s, store.get(i, s))))
    store.sdo_write(0x2003, 0, (1250).to_bytes(2, "little", signed=True))
    store.set(0x2003, 0, -400)
    assert seen == [(0x2003, 0, 1250), (0x2003, 0, -400)]


def test_restore_gives_power_on_values_of_an_area(store):
    store.set(0x2000, 0, 7)
    store.set(0x1017, 0, 55)
    store.restore(0x1000, 0x1FFF)
    assert store.get(0x1017) == 1000 and store.get(0x2000) == 7
    store.restore()
    assert store.get(0x2000) == 0
