"""`restbus --uds` refuses identifiers already taken, naming them as every output does (``0x7E0``:
11-bit, three upper-case hex digits), in one line with exit status 2."""

from __future__ import annotations

from pathlib import Path

import cantools

import stack.cli as cli

DBC = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"


def _run(capsys, *uds):
    argv = ["restbus", str(DBC), "--duration", "0.05"]
    for spec in uds:
        argv += ["--uds", spec]
    code = cli.main(argv)
    return code, capsys.readouterr()


def test_an_identifier_given_to_two_uds_nodes_is_one_line(capsys):
    code, cap = _run(capsys, "ECM:0x7e0:0x7e8", "TCM:0x7e1:0x7e0")
    assert code == 2 and cap.err.count("\n") == 1, cap.err
    assert "--uds TCM:0x7E1:0x7E0: identifier 0x7E0 is already used by --uds ECM" in cap.err


def test_an_identifier_of_a_database_message_is_one_line(capsys):
    msg = cantools.database.load_file(str(DBC)).get_message_by_name("EngineData")
    assert not msg.is_extended_frame
    code, cap = _run(capsys, f"ECM:{msg.frame_id}:0x7e8")
    expected = f"0x{msg.frame_id:03X}"  # 11 bits: 3 hex digits, upper case
    assert code == 2 and cap.err.count("\n") == 1, cap.err
    assert f"--uds ECM:{expected}:0x7E8: identifier of message EngineData in the database" in cap.err
