"""EDS values the canopen library reads leniently (`profiles.canopen.edsvalues`), and a generated
batch of mutations of the shipped EDS: every mutation is read, or refused with one `EdsError`
naming the file — never another exception — and every value that breaks a CiA 306 rule is
refused, never run as 0.

The rules the batch checks against are written here from CiA 306-1 (4.6.3, object
descriptions), not taken from the code under test: ``ObjectType``, ``DataType``, ``PDOMapping``,
``SubNumber``, ``LowLimit``, ``HighLimit`` and a number's ``DefaultValue``/``ParameterValue`` are
integers in C notation (a REAL's value and limits decimal numbers; a default may be
``$NODEID+<number>``), ``AccessType`` is one of ro, wo, rw, rwr, rww, const."""

import random
import re

import pytest

import stack.cli as cli
from profiles.canopen.device import CanopenDevice
from profiles.canopen.dictionary import DEFAULT_EDS, EdsError, ObjectStore, load_od
from profiles.canopen.edsvalues import nodeid_expression
from stack.bus.sim import SimBus

NODE_ID = 9
SRC = DEFAULT_EDS.read_text()


def _with(tmp_path, text, name="mutant.eds"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _set(text: str, section: str, key: str, value: str) -> str:
    """``text`` with ``key`` of ``[section]`` set to ``value`` (added when missing)."""
    head = f"[{section}]\n"
    start = text.index(head) + len(head)
    end = text.find("\n[", start)
    end = len(text) if end < 0 else end + 1
    body = text[start:end]
    pattern = re.compile(rf"^{re.escape(key)}=.*$", re.MULTILINE)
    body = pattern.sub(f"{key}={value}", body, count=1) if pattern.search(body) else f"{key}={value}\n" + body
    return text[:start] + body + text[end:]


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        ("1017", "DefaultValue", "abc", r"\[1017\] DefaultValue 'abc': not a number, as its data type \(UNSIGNED16\)"),
        ("1017", "LowLimit", "abc", r"\[1017\] LowLimit 'abc': not a number"),
        ("1017", "HighLimit", "0xZZ", r"\[1017\] HighLimit '0xZZ': not a number"),
        ("1800", "SubNumber", "abc", r"\[1800\] SubNumber 'abc': not a number"),
        ("1800", "SubNumber", "0x7", r"\[1800\] SubNumber '0x7': 6 sub-index section\(s\) follow"),
        ("1017", "AccessType", "readwrite", r"\[1017\] AccessType 'readwrite': not an access type of CiA 306"),
        ("1800sub1", "DefaultValue", "$NODEID+", r"\[1800sub1\] DefaultValue '\$NODEID\+': a '\+' with no number"),
        ("1800sub1", "DefaultValue", "$NODEID*2", r"DefaultValue '\$NODEID\*2': not \$NODEID, \$NODEID\+<number>"),
        ("1800sub1", "DefaultValue", "$NODEID+0x180+$NODEID", r"not \$NODEID, \$NODEID\+<number>"),
        ("1800sub1", "DefaultValue", "$NODEID+0x700", r"TPDO1 COB-ID\): CAN-ID 0x709 is restricted \(CiA 301 7\.3\.5"),
    ],
)
def test_values_the_library_would_let_through_are_refused(tmp_path, section, key, value, message):
    path = _with(tmp_path, _set(SRC, section, key, value))
    with pytest.raises(EdsError, match=message) as exc:
        load_od(path, NODE_ID)
    assert str(exc.value).startswith(f"{path}: ") and "\n" not in str(exc.value)


def test_low_limit_above_high_limit_is_refused(tmp_path):
    text = _set(_set(SRC, "1017", "LowLimit", "200"), "1017", "HighLimit", "100")
    with pytest.raises(EdsError, match=r"\[1017\] LowLimit '200' is above HighLimit '100'"):
        load_od(_with(tmp_path, text), NODE_ID)


@pytest.mark.parametrize(
    "value, expected",
    [("$NODEID+0x180", 0x180 + NODE_ID), ("0x200+$NODEID", 0x200 + NODE_ID), ("$nodeid + 384", 384 + NODE_ID)],
)
def test_nodeid_relative_cob_ids_are_what_the_device_sends_on(tmp_path, value, expected):
    path = _with(tmp_path, _set(SRC, "1800sub1", "DefaultValue", value))
    assert ObjectStore(load_od(path, NODE_ID)).u(0x1800, 1) == expected
    # and the device's TPDO1 uses that CAN-ID
    bus = SimBus(500_000, record=False)
    device = CanopenDevice(bus.node("dev"), NODE_ID, path)
    assert device.tpdos[0].can_id == expected


def test_nodeid_alone_is_the_node_id_not_zero(tmp_path):
    # the library reads "$NODEID" alone as no value (0): the dictionary said COB-ID 0; CiA 306
    # relative values add the node-ID, here to nothing. 0x009 is then a restricted CAN-ID, so
    # such a TPDO must be marked unused (bit 31) to load
    od = load_od(_with(tmp_path, _set(SRC, "1802sub1", "DefaultValue", "0x80000000+$NODEID")), NODE_ID)
    assert ObjectStore(od).u(0x1802, 1) == 0x8000_0000 + NODE_ID
    with pytest.raises(EdsError, match=r"TPDO3 COB-ID\): CAN-ID 0x009 is restricted"):
        load_od(_with(tmp_path, _set(SRC, "1802sub1", "DefaultValue", "$NODEID")), NODE_ID)
    assert nodeid_expression("$NODEID", NODE_ID) == NODE_ID


# ------------------------------------------------------------------------------ the generated batch
HOSTILE = ("abc", "", "0x", "-1", "1e3", "1.5", "99999999999999999999999", "$NODEID+", "$NODEID+0x10", "ro", "x" * 300)
NUMERIC_KEYS = ("ObjectType", "DataType", "PDOMapping", "SubNumber", "LowLimit", "HighLimit")
ACCESS = {"ro", "wo", "rw", "rwr", "rww", "const"}
REAL = {0x0008, 0x0011}
STRINGS = {0x0009, 0x000A, 0x000B, 0x000F}


def _sections(text: str) -> dict[str, dict[str, str]]:
    out: dict[str, dict[str, str]] = {}
    cur = None
    for line in text.splitlines():
        m = re.fullmatch(r"\[([^\]]+)\]", line.strip())
        if m:
            cur = out.setdefault(m.group(1), {})
        elif cur is not None and "=" in line:
            k, _, v = line.partition("=")
            cur[k.strip()] = v.strip()
    return out


def _is_number(text: str, real: bool) -> bool:
    try:
        int(text, 0)
        return True
    except ValueError:
        pass
    if real:
        try:
            float(text)
            return True
        except ValueError:
            return False
    return False


def _breaks_cia_306(section: dict[str, str], key: str, value: str, name: str) -> bool:
    """True for a value CiA 306 forbids outright (whatever the rest of the file)."""
    if key == "SubNumber" and ("sub" in name.lower() or section.get("ObjectType", "0x7") not in ("0x8", "0x9")):
        return False  # a key of an array or a record, nothing reads it elsewhere
    if section.get("ObjectType", "0x7") in ("0x8", "0x9") and key not in ("ObjectType", "SubNumber"):
        return False  # an array or a record: its values are its sub-indices'
    if not value:
        return key in ("ObjectType", "DataType", "PDOMapping", "SubNumber", "AccessType")
    dtype = int(section.get("DataType", "0"), 0) if _is_number(section.get("DataType", "0"), False) else 0
    if key == "AccessType":
        return value.lower() not in ACCESS
    if key in NUMERIC_KEYS:
        return not _is_number(value, dtype in REAL and key in ("LowLimit", "HighLimit"))
    if key in ("DefaultValue", "ParameterValue") and dtype and dtype not in STRINGS and dtype != 0x000F:
        if re.fullmatch(r"\$NODEID\+(0[xX][0-9A-Fa-f]+|\d+)", value):
            return False
        return not _is_number(value, dtype in REAL)
    return False


def _mutations(n: int = 150) -> list[tuple[str, str, str]]:
    rng = random.Random(306)  # the same batch every run
    sections = _sections(SRC)
    keys = ("DefaultValue", "AccessType", "LowLimit", "HighLimit", "SubNumber", "PDOMapping", "DataType", "ObjectType")
    everything = [
        (s, k, v)
        for s in sections
        if re.fullmatch(r"[0-9A-Fa-f]{4}(sub[0-9A-Fa-f]+)?", s)
        for k in keys
        for v in HOSTILE
    ]
    return rng.sample(everything, n)


def test_a_generated_batch_of_mutations_is_read_or_refused_in_one_line(tmp_path):
    """Every second mutation of the batch (the other half runs with ``-m campaign``)."""
    _read_or_refuse(tmp_path, _mutations()[::2])


@pytest.mark.campaign
def test_the_other_half_of_the_mutations(tmp_path):
    _read_or_refuse(tmp_path, _mutations()[1::2])


def _read_or_refuse(tmp_path, mutations: list[tuple[str, str, str]]) -> None:
    sections = _sections(SRC)
    accepted = refused = 0
    for section, key, value in mutations:
        path = _with(tmp_path, _set(SRC, section, key, value))
        what = f"[{section}] {key}={value[:20]!r}"
        bus = SimBus(500_000, record=False)
        try:
            # the device reads the file with `load_od`; a dictionary it cannot run on (a PDO
            # mapping it cannot use) is refused when it is made, as `canstack canopen` makes it:
            # also one EdsError
            device = CanopenDevice(bus.node("dev"), NODE_ID, path)
        except EdsError as exc:  # anything else escapes and fails the test with its traceback
            text = str(exc)
            assert text.startswith(f"{path}: ") and "\n" not in text and "Traceback" not in text, what
            refused += 1
            continue
        assert not _breaks_cia_306(sections[section], key, value, section), f"{what} was accepted"
        # what loads runs: a device on the simulated bus boots and answers for 5 ms
        device.start()
        bus.run(duration=5_000_000)
        accepted += 1
    assert accepted and refused  # each half has both kinds


def _bad_mutations(n: int = 8) -> list[tuple[str, str, str]]:
    sections = _sections(SRC)
    return [m for m in _mutations() if _breaks_cia_306(sections[m[0]], m[1], m[2], m[0])][:n]


@pytest.mark.parametrize("section, key, value", _bad_mutations())
def test_the_command_refuses_a_mutated_eds_with_one_line_and_status_2(tmp_path, capsys, section, key, value):
    path = _with(tmp_path, _set(SRC, section, key, value))
    with pytest.raises(EdsError) as exc:
        load_od(path, NODE_ID)
    code = cli.main(["canopen", str(path), "--node-id", str(NODE_ID), "--interface", "virtual", "--duration", "0.01"])
    out, err = capsys.readouterr()
    assert (code, out, err) == (2, "", f"canstack: error: {exc.value}\n")
