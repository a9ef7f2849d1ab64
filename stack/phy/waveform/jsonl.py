"""Frames and decoded records as JSON lines, one object a line: what `canstack decode --json`
writes and `canstack render` reads.

Keys: t (seconds, optional when reading), id (integer), extended, remote, dlc, data (hex), crc
(CRC-15, or CRC-17/21 of a CAN FD frame; checked against the frame when reading), crc_ok, ack;
a CAN FD frame adds fd (true), brs and esi; an error record adds ``error``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from typing import Any

from stack.phy.waveform.decode import RxRecord
from stack.wire.frame import Frame

__all__ = ["record_to_json", "frames_from_jsonl"]


def record_to_json(rec: RxRecord) -> dict[str, Any]:
    """The JSON-lines form of a record: t, id, extended, remote, dlc, data (hex), crc, crc_ok,
    ack; CAN FD records add fd, brs and esi (classical records keep exactly the keys above);
    error records add ``error`` {kind, field, bit (index in the field), position (bit from
    SOF), flag (error flag seen)}."""
    out: dict[str, Any] = {
        "t": rec.t,
        "id": rec.can_id,
        "extended": rec.extended,
        "remote": rec.remote,
        "dlc": rec.dlc,
        "data": rec.data.hex(),
        "crc": rec.crc,
        "crc_ok": rec.crc_ok,
        "ack": rec.ack,
    }
    if rec.fd:
        out.update(fd=True, brs=rec.brs, esi=rec.esi)
    if rec.error is not None:
        out["error"] = {
            "kind": rec.error.kind,
            "field": rec.error.field.value,
            "bit": rec.error.index,
            "position": rec.error.position,
            "flag": rec.error_flag,
        }
    return out


def frames_from_jsonl(lines: Iterable[str], source: str = "input") -> list[tuple[float | None, Frame]]:
    """Parse JSON lines with decode's keys (id, extended, remote, dlc, data hex, fd, brs, esi; t
    optional, crc optional and checked against the frame's CRC when given) into (t, Frame) pairs.

    Error records (with an ``error`` key) are skipped: they are not frames a node sends.
    """
    out: list[tuple[float | None, Frame]] = []
    for lineno, text in enumerate(lines, 1):
        text = text.strip()
        if not text:
            continue
        where = f"{source} line {lineno}"
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{where}: not JSON ({exc.msg})") from None
        if not isinstance(obj, dict):
            raise ValueError(f"{where}: expected a JSON object per line, got {type(obj).__name__}")
        if "error" in obj:
            continue
        if "id" not in obj or not isinstance(obj["id"], int) or isinstance(obj["id"], bool):
            raise ValueError(f"{where}: 'id' must be an integer identifier")
        data_hex = obj.get("data", "") or ""
        try:
            data = bytes.fromhex(data_hex)
        except (ValueError, TypeError):
            raise ValueError(f"{where}: 'data' {data_hex!r} is not a hex string") from None
        remote = bool(obj.get("remote", False))
        try:
            frame = Frame(
                obj["id"],
                b"" if remote else data,
                extended=bool(obj.get("extended", False)),
                remote=remote,
                dlc=obj.get("dlc"),
                fd=bool(obj.get("fd", False)),
                brs=bool(obj.get("brs", False)),
                esi=bool(obj.get("esi", False)),
            )
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        crc = obj.get("crc")
        if crc is not None and crc != frame.bits.crc:
            fb = frame.bits
            raise ValueError(
                f"{where}: crc {crc} (0x{crc:04X}) does not match the frame's CRC-{fb.crc_width} 0x{fb.crc:04X}"
            )
        t = obj.get("t")
        if t is not None and (not isinstance(t, (int, float)) or isinstance(t, bool) or not 0 <= t < math.inf):
            raise ValueError(f"{where}: 't' {t!r} must be a time in seconds >= 0")
        out.append((None if t is None else float(t), frame))
    return out
