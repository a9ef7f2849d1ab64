"""Captures of the CAN_RX pin read from files: sigrok session files (.sr, a zip with ``metadata``
and ``logic-1`` or ``logic-1-N`` chunks), VCD (read with pyvcd's tokenizer) and raw files of one
byte per sample, each into a `Capture` of one channel (0 dominant, 1 recessive).

`read_capture` recognises the format by content; every malformed file is a ValueError naming the
file and what is wrong with it.
"""

from __future__ import annotations

import configparser
import math
import re
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import NamedTuple

from stack.phy.waveform.levels import DOMINANT, RECESSIVE

__all__ = ["Capture", "read_capture", "read_sigrok", "read_vcd", "read_raw", "missing_input", "MAX_CAPTURE_SAMPLES"]

#: Samples a capture may expand to when a VCD's change times are laid on a sample grid: the
#: capture is held in memory, one byte a sample.
MAX_CAPTURE_SAMPLES = 400_000_000


@dataclass(frozen=True)
class Capture:
    """One logic channel of a recording: ``samples`` holds one byte per sample, 0 (dominant) or
    1 (recessive); ``samplerate`` in Hz; ``channel`` the channel's name; ``source`` the file."""

    samples: bytes
    samplerate: float
    channel: str
    source: str = ""
    # the rate the recording was made at, when the samples were subdivided for the receiver
    # (a VCD's edge grid): the decoder's rescue for coarse captures goes by this one
    native_rate: float | None = None

    @property
    def duration(self) -> float:
        """Length of the recording in seconds."""
        return len(self.samples) / self.samplerate


def _bit_table(bit: int) -> bytes:
    return bytes((x >> bit) & 1 for x in range(256))


_UNITS = {"": 1, "hz": 1, "khz": 1e3, "mhz": 1e6, "ghz": 1e9}


def _parse_samplerate(text: str) -> float:
    m = re.fullmatch(r"\s*([0-9.]+)\s*([kMG]?Hz)?\s*", text, re.IGNORECASE)
    if not m:
        raise ValueError(f"samplerate {text!r} in sigrok metadata is not a frequency like '4 MHz'")
    return float(m.group(1)) * _UNITS[(m.group(2) or "").lower()]


def _select_channel(names: Sequence[str | None], channel: str | int | None, what: str) -> int:
    """Index of the channel chosen by name or by 0-based index (``#N`` forces an index); a
    number that is one channel's name and another's index is refused as ambiguous; a message
    lists the channels. A None name is a bit no channel is recorded on."""
    listing = ", ".join(f"{i}={n!r}" for i, n in enumerate(names) if n is not None)
    if channel is None:
        if "CAN_RX" in names:
            return names.index("CAN_RX")
        present = [i for i, n in enumerate(names) if n is not None]
        if len(present) == 1:
            return present[0]
        raise ValueError(f"{what} has several channels ({listing}): choose one with --channel")
    text = str(channel)
    if text.startswith("#"):  # explicitly an index
        try:
            idx = int(text[1:])
        except ValueError:
            idx = -1
        if 0 <= idx < len(names) and names[idx] is not None:
            return idx
        raise ValueError(f"channel index {text!r} not in {what}: available channels are {listing}")
    try:
        idx = int(text) if not isinstance(channel, bool) else -1
    except ValueError:
        idx = -1
    by_index = idx if 0 <= idx < len(names) and names[idx] is not None else None
    if text in names:
        by_name = names.index(text)
        if by_index is not None and by_index != by_name:
            raise ValueError(
                f"channel {text!r} is ambiguous in {what}: the channel named {text!r} is index "
                f"{by_name}, index {idx} is {names[idx]!r}; say --channel {names[idx]} or "
                f"--channel '#{idx}' (channels: {listing})"
            )
        return by_name
    if by_index is not None:
        return by_index
    raise ValueError(f"channel {text!r} not found in {what}: available channels are {listing}")


def read_sigrok(path: str | Path, channel: str | int | None = None) -> Capture:
    """Read one channel of a sigrok session file (.sr).

    Format: a zip with an ini file ``metadata`` ([device 1]: ``capturefile``, ``unitsize`` bytes a
    sample, ``samplerate``, ``probe{k+1}`` the name of bit k) and the samples in ``logic-1`` or in
    chunks ``logic-1-1``, ``logic-1-2``, ... (concatenated in numeric order). The channel is chosen
    by name, else by 0-based bit index; default CAN_RX, or the only channel.
    """
    path = Path(path)
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise ValueError(f"{path}: not a sigrok session file (not a zip archive)") from None
    with zf:
        names = zf.namelist()
        if "metadata" not in names:
            raise ValueError(f"{path}: not a sigrok session file (zip without 'metadata')")
        cp = configparser.ConfigParser(interpolation=None)
        try:
            cp.read_string(_read_member(zf, path, "metadata").decode("utf-8", "replace"))
        except configparser.Error as exc:
            first = str(exc).splitlines()[0]
            raise ValueError(f"{path}: sigrok metadata is not an ini file ({first})") from None
        dev = next((s for s in cp.sections() if s.startswith("device")), None)
        if dev is None:
            raise ValueError(f"{path}: sigrok metadata has no [device N] section")
        sec = cp[dev]
        base = sec.get("capturefile", "logic-1")
        try:
            unitsize = int(sec.get("unitsize", "1"))
        except ValueError as exc:
            raise ValueError(f"{path}: sigrok metadata: {exc}") from None
        if not 1 <= unitsize <= 8:
            raise ValueError(f"{path}: sigrok metadata: unitsize {unitsize} outside 1..8 bytes a sample")
        if "samplerate" not in sec:
            raise ValueError(f"{path}: sigrok metadata gives no samplerate")
        rate = _parse_samplerate(sec["samplerate"])
        # a sample of ``unitsize`` bytes holds 8 x unitsize channels: a probe numbered beyond
        # that has no data in the file, and sizing the channel list by it would let one
        # metadata line allocate gigabytes ('probe999999999')
        width = 8 * unitsize
        probes: dict[int, str] = {}
        for key, value in sec.items():
            m = re.fullmatch(r"probe(\d+)", key)
            if m:
                num = int(m.group(1))
                if not 1 <= num <= width:
                    raise ValueError(
                        f"{path}: sigrok metadata names {key!r}, but a sample of unitsize {unitsize} "
                        f"holds {width} channels (probe1..probe{width})"
                    )
                probes[num - 1] = value
        chan_names = [probes.get(i) for i in range(width)]
        bit = _select_channel(chan_names, channel, str(path))
        chan_name = chan_names[bit]
        assert chan_name is not None  # _select_channel chooses only channels that have a name
        if base in names:
            parts = [base]
        else:
            chunk = re.compile(re.escape(base) + r"-(\d+)$")
            nums = sorted((int(m.group(1)), n) for n in names if (m := chunk.match(n)))
            parts = [n for _, n in nums]
        if not parts:
            raise ValueError(f"{path}: sigrok session without sample data ('{base}' or '{base}-N')")
        raw = b"".join(_read_member(zf, path, p) for p in parts)
    if unitsize > 1:
        raw = raw[bit // 8 :: unitsize]
    return Capture(raw.translate(_bit_table(bit % 8)), rate, chan_name, str(path))


def _read_member(zf: zipfile.ZipFile, path: Path, member: str) -> bytes:
    """One member of a session archive; a damaged member (CRC mismatch, bad deflate data, cut
    short) is a ValueError naming the file and the member, since the archive's directory being
    intact says nothing about the data behind it."""
    try:
        return zf.read(member)
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as exc:
        raise ValueError(f"{path}: sigrok session member {member!r} is damaged ({exc})") from None


def read_raw(path: str | Path, samplerate: float | None, channel: str | int | None = None) -> Capture:
    """Read a raw file of one byte per sample; the channel is a bit index 0..7.

    A samplerate must be given (the file carries none). Default channel: the one bit that
    changes in the file; if several do, they are listed and one must be chosen.
    """
    if not samplerate or samplerate <= 0:
        raise ValueError(f"{path}: a raw sample file carries no samplerate: give --samplerate")
    data = Path(path).read_bytes()
    if not data:
        raise ValueError(f"{path}: empty file, no samples")
    if channel is None:
        all_or = 0
        all_and = 0xFF
        for v in set(data):
            all_or |= v
            all_and &= v
        seen = all_or & ~all_and
        bits = [b for b in range(8) if seen >> b & 1]
        if len(bits) > 1:
            raise ValueError(
                f"{path}: bits {', '.join(map(str, bits))} change in this raw file: choose one with --channel"
            )
        bit = bits[0] if bits else 0
    else:
        try:
            bit = int(str(channel))
        except ValueError:
            bit = -1
        if not 0 <= bit <= 7:
            raise ValueError(f"channel {channel!r} of a raw file must be a bit index 0..7")
    return Capture(data.translate(_bit_table(bit)), float(samplerate), str(bit), str(path))


class _ChannelError(ValueError):
    """A complete message about the file (a channel that is not in it, times that go
    backwards), raised through the VCD reader's error wrapping unchanged."""


def _approx(x: float | int | Fraction) -> str:
    """A number for a message, 3 significant digits, also beyond the range of a float (a VCD
    time is an integer of any size, its rate a fraction that may underflow)."""
    q = Fraction(x)
    if q == 0 or Fraction(1, 10**300) < abs(q) < 10**300:
        return f"{float(q):.3g}"
    return f"about 1e{len(str(abs(q.numerator))) - len(str(q.denominator))}"


def _vcd_time(t: int) -> str:
    """A VCD time stamp as written (#t), shortened when it has more digits than a message can
    usefully show."""
    digits = str(t)
    return f"#{t}" if len(digits) <= 15 else f"#{digits[:6]}... ({len(digits)} digits)"


_TS_EXP = {"s": 0, "ms": -3, "us": -6, "ns": -9, "ps": -12, "fs": -15}


class _VcdSignal(NamedTuple):
    """What the tokenizer pass keeps of a VCD file: the chosen signal's level changes."""

    changes: list[tuple[int, int]]  # (time in timescale units, level 0/1), levels alternate
    end: int  # the last time stamp in the file
    timescale: Fraction  # seconds per time unit
    name: str  # the signal's reference name


def _scan_vcd(path: Path, channel: str | int | None) -> _VcdSignal | None:
    """One pass of pyvcd's tokenizer: the declarations, the timescale, and the value changes of
    the signal chosen at ``$enddefinitions`` (None without one); times must not decrease
    (IEEE 1364)."""
    from vcd.reader import TokenKind, tokenize

    decls: list[tuple[str, str, int]] = []  # (name, id_code, size)
    scope: list[str] = []
    timescale = Fraction(1, 10**9)
    changes: list[tuple[int, int]] = []
    want: str | None = None
    chan_name = ""
    now = 0
    now_line = 0
    level = 1
    with open(path, "rb") as fh:
        for tok in tokenize(fh):
            kind = tok.kind
            if kind is TokenKind.CHANGE_TIME:
                # IEEE 1364 dumps times in increasing order; a reader that accepted a step
                # back would silently draw the changes after it at the wrong place
                t = tok.time_change
                if t < now:
                    raise _ChannelError(
                        f"{path} line {tok.span.start.line}: time {_vcd_time(t)} is earlier than {_vcd_time(now)} "
                        f"(line {now_line}): VCD times must not decrease"
                    )
                now = t
                now_line = tok.span.start.line
            elif kind is TokenKind.CHANGE_SCALAR:
                scalar = tok.scalar_change
                if scalar.id_code == want:
                    v = 0 if scalar.value == "0" else 1
                    if v != level or not changes:
                        changes.append((now, v))
                        level = v
            elif kind is TokenKind.CHANGE_VECTOR:
                vector = tok.vector_change
                if vector.id_code == want:
                    v = 0 if vector.value == 0 else 1
                    if v != level or not changes:
                        changes.append((now, v))
                        level = v
            elif kind is TokenKind.SCOPE:
                scope.append(tok.scope.ident)
            elif kind is TokenKind.UPSCOPE:
                if scope:
                    scope.pop()
            elif kind is TokenKind.VAR:
                var = tok.var
                decls.append((".".join([*scope, var.reference]), var.id_code, var.size))
            elif kind is TokenKind.TIMESCALE:
                ts = tok.timescale
                timescale = Fraction(ts.magnitude) * Fraction(10) ** _TS_EXP[ts.unit.value]
            elif kind is TokenKind.ENDDEFINITIONS:
                want, chan_name = _choose_vcd_signal(path, decls, channel)
    if want is None:
        return None  # no $enddefinitions: not a VCD file
    return _VcdSignal(changes, now, timescale, chan_name)


def _choose_vcd_signal(path: Path, decls: list[tuple[str, str, int]], channel: str | int | None) -> tuple[str, str]:
    """(id code, short name) of the signal ``channel`` names: a full scope.name first, else as
    `_select_channel` chooses among the short names."""
    if not decls:
        raise ValueError(f"{path}: VCD file declares no signals")
    full = [d[0] for d in decls]
    short = [name.rsplit(".", 1)[-1] for name in full]
    text = None if channel is None else str(channel)
    if text is not None and text in full:
        idx = full.index(text)
    else:
        try:
            idx = _select_channel(short, channel, str(path))
        except ValueError as exc:
            raise _ChannelError(str(exc)) from None
    return decls[idx][1], short[idx]


def read_vcd(
    path: str | Path,
    channel: str | int | None = None,
    samplerate: float | None = None,
    bitrate: float | None = None,
) -> Capture:
    """Read one 1-bit signal of a VCD file (pyvcd's tokenizer) into samples.

    The signal is chosen by reference name (or scope.name), else by 0-based index in declaration
    order; default CAN_RX or the only signal. Values x/z count as recessive (an undriven bus).
    Without ``samplerate`` the signal is sampled exactly: the sample period is the greatest common
    divisor of the change times, divided further (still exact) until a bit of ``bitrate`` spans
    at least 16 samples, so every edge lands on a sample boundary.
    """
    from vcd.reader import VCDParseError

    path = Path(path)
    try:
        sig = _scan_vcd(path, channel)
    except _ChannelError:
        raise
    except (VCDParseError, ValueError, KeyError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable VCD file ({exc})") from None
    if sig is None:
        raise ValueError(f"{path}: not a VCD file (no $enddefinitions)")
    changes, timescale = sig.changes, sig.timescale
    if not changes:
        raise ValueError(f"{path}: signal {sig.name!r} has no value changes")
    end = max(sig.end, changes[-1][0])
    # exact arithmetic until the sample count is known to be sane: a change time of 1e309
    # units is a valid VCD integer, but as a float its rate underflows to 0 (or its ratio to
    # the bitrate overflows)
    native_q: Fraction | None = None
    if samplerate:
        rate_q = Fraction(samplerate).limit_denominator(10**6)
        step = 1 / (rate_q * timescale)
    else:
        g = end
        for t, _ in changes:
            g = math.gcd(g, t)
        step = Fraction(g or 1)
        rate_q = 1 / (step * timescale)
        native_q = rate_q
        if bitrate and rate_q < 16 * Fraction(bitrate):
            # an edge-exact signal stays exact at any integer multiple of its rate
            k = math.ceil(16 * Fraction(bitrate) / rate_q)
            step /= k
            rate_q *= k
    total = math.ceil(end / step)
    if total > MAX_CAPTURE_SAMPLES:
        raise ValueError(
            f"{path}: the signal runs to time {_vcd_time(end)} ({_approx(end * timescale)} s): {_approx(total)} samples at "
            f"{_approx(rate_q)} Hz, more than {MAX_CAPTURE_SAMPLES:,} (cut the recording, or give a lower --samplerate)"
        )
    rate = float(rate_q)
    if not 0 < rate < math.inf:
        raise ValueError(
            f"{path}: the change times give a sample period of {_approx(step * timescale)} s, "
            f"{_approx(rate_q)} samples/s, which is no usable rate: give --samplerate"
        )
    parts: list[bytes] = []
    pos = 0
    level = 1  # before the first value change the bus counts as idle (recessive)
    for t, v in changes:
        idx = math.ceil(t / step)
        if idx > pos:
            parts.append((RECESSIVE if level else DOMINANT) * (idx - pos))
            pos = idx
        level = v
    parts.append((RECESSIVE if level else DOMINANT) * max(1, total - pos))
    native = None if native_q is None else float(native_q)
    return Capture(b"".join(parts), rate, sig.name, str(path), native)


def missing_input(path: str | Path, what: str = "file") -> str:
    """Why an input file cannot be opened, in words: a directory, a path through a file, or no
    such file (the OS's own message says 'Not a directory' without saying which part)."""
    p = Path(path)
    if p.is_dir():
        return f"{p}: is a directory, not a {what}"
    parent = p.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        return f"{p}: {str(parent)!r} is a file, not a directory"
    return f"{p}: no such {what}"


def read_capture(
    path: str | Path,
    channel: str | int | None = None,
    samplerate: float | None = None,
    bitrate: float | None = None,
) -> Capture:
    """Read a capture, recognising the format by content: a zip is a sigrok session, text that
    starts with a VCD keyword is VCD, anything else is raw samples (which need a samplerate)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(missing_input(path, "capture file"))
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head[:4] == b"PK\x03\x04":
        return read_sigrok(path, channel)
    stripped = head.lstrip()
    if stripped[:1] == b"$" and re.match(rb"\$(date|version|timescale|comment|scope|var)\b", stripped):
        return read_vcd(path, channel, samplerate, bitrate)
    if path.suffix.lower() in (".sr", ".vcd"):
        raise ValueError(f"{path}: not a capture: the content is neither a sigrok session (zip) nor VCD")
    if not samplerate:
        raise ValueError(
            f"{path}: not a capture: neither a sigrok session (.sr zip) nor VCD; "
            "a raw one-byte-per-sample file needs --samplerate"
        )
    return read_raw(path, samplerate, channel)
