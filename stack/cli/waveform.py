"""`canstack decode` and `canstack render`: CAN_RX waveforms on the command line
(`stack.phy.waveform`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from stack.cli import SAMPLE_POINT_HELP, format_id, parse_sample_point, plural
from stack.cli.runs import check_output, writing
from stack.phy.waveform import (
    MAX_RENDER_SAMPLES,
    BitReceiver,
    RxRecord,
    decode_file,
    frames_from_jsonl,
    missing_input,
    record_to_json,
    render_edges,
    runs_to_raw,
    write_raw,
    write_vcd,
)

__all__ = ["register"]


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not v > 0 or math.isinf(v):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive number")
    return v


def _fmt(r: RxRecord) -> str:
    """std/ext, R for a remote frame, F for CAN FD, B for a bit rate switch, E for ESI."""
    flags = ("R" if r.remote else "") + ("F" if r.fd else "") + ("B" if r.brs else "") + ("E" if r.esi else "")
    return ("ext" if r.extended else "std") + flags


def _format_table(recs: Sequence[RxRecord]) -> str:
    # CAN FD records widen the columns they need (classical tables keep their layout)
    wf = max([4] + [len(_fmt(r)) for r in recs])
    wd = max([23] + [3 * len(r.data) - 1 for r in recs if r.fd])
    wc = max([6] + [8 for r in recs if r.fd and r.crc is not None])
    lines = [f"{'time/s':>12}  {'id':>10}  {'fmt':{wf}} {'dlc':>3}  {'data':{wd}}  {'crc':{wc}}  crc stuff form ack"]
    for r in recs:
        ident = "-" if r.can_id is None else format_id(r.can_id, r.extended)
        dlc = "-" if r.dlc is None else str(r.dlc)
        data = "remote" if r.remote else r.data.hex(" ")
        crc = "-" if r.crc is None else f"0x{r.crc:06X}" if r.fd else f"0x{r.crc:04X}"
        ok = lambda b: "ok " if b else "ERR"  # noqa: E731
        crc_ok = ok(r.crc_ok) if r.crc is not None else " - "
        row = (
            f"{r.t:12.6f}  {ident:>10}  {_fmt(r):{wf}} {dlc:>3}  {data:{wd}}  {crc:{wc}}  {crc_ok} {ok(r.stuff_ok)}   "
            f"{ok(r.form_ok)}  {'yes' if r.ack else 'no'}"
        )
        if r.error is not None:
            row += f"  {r.error}" + (" [error flag]" if r.error_flag else "")
        lines.append(row)
    good = sum(1 for r in recs if r.ok)
    lines.append(f"{plural(good, 'frame')}, {plural(len(recs) - good, 'error record')}")
    return "\n".join(lines)


def _cmd_decode(args: argparse.Namespace) -> int:
    if args.samplerate:
        # the options' own rules (samples a bit, sample point, SJW) before a large file is read
        BitReceiver(
            args.bitrate,
            args.samplerate,
            sample_point=args.sample_point,
            sjw=args.sjw,
            data_bitrate=args.data_bitrate,
            data_sample_point=args.data_sample_point,
        )
    recs = decode_file(
        args.file,
        args.bitrate,
        channel=args.channel,
        samplerate=args.samplerate,
        sample_point=args.sample_point,
        sjw=args.sjw,
        retry=not args.no_retry,
        data_bitrate=args.data_bitrate,
        data_sample_point=args.data_sample_point,
    )
    out = sys.stdout
    if args.json:
        for r in recs:
            out.write(json.dumps(record_to_json(r)) + "\n")
    else:
        out.write(_format_table(recs) + "\n")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    target, option = (args.vcd, "--vcd") if args.vcd else (args.raw, "--raw")
    check_output(target, option)
    src = Path(args.frames)
    if str(src) == "-":
        text = sys.stdin.read().splitlines()
    else:
        if not src.is_file():
            raise ValueError(missing_input(src, "frames file"))
        try:
            text = src.read_text(encoding="utf-8").splitlines()
        except UnicodeDecodeError as exc:
            raise ValueError(f"{src}: not a text file of JSON lines ({exc.reason} at byte {exc.start})") from None
    pairs = frames_from_jsonl(text, str(src))
    if not pairs:
        raise ValueError(f"{src}: no frames to render")
    frames = [f for _, f in pairs]
    times = [t for t, _ in pairs]
    # the waveform is written whole: bound it before building it (a far-off 't' would need
    # gigabytes); frames without 't' follow each other back to back
    span = max((t for t in times if t is not None), default=0.0) + sum(f.bits.length + 3 for f in frames) / args.bitrate
    if span * args.samplerate > MAX_RENDER_SAMPLES:
        raise ValueError(
            f"{src}: the frames span {span:g} s, {span * args.samplerate:.3g} samples at "
            f"{args.samplerate:g} samples/s: more than {MAX_RENDER_SAMPLES:,} (lower 't' or --samplerate)"
        )
    runs, total, _ = render_edges(
        frames,
        args.bitrate,
        args.samplerate,
        times=times,
        drift=args.drift,
        jitter=args.jitter,
        seed=args.seed,
        data_bitrate=args.data_bitrate,
        sample_point=args.sample_point,
        data_sample_point=args.data_sample_point,
    )
    if args.vcd:
        writing(
            args.vcd,
            "--vcd",
            lambda: write_vcd(
                args.vcd,
                runs,
                args.samplerate,
                name=args.name,
                comment=f"canstack render: {len(frames)} frames at {args.bitrate:g} bit/s"
                + (f" (data {args.data_bitrate:g} bit/s)" if args.data_bitrate else "")
                + f", {args.samplerate:g} samples/s",
            ),
        )
    else:
        writing(args.raw, "--raw", lambda: write_raw(args.raw, runs_to_raw(runs, args.raw_bit)))
    print(
        f"render: {plural(len(frames), 'frame')}, {plural(total, 'sample')} "
        f"({total / args.samplerate:.6g} s at {args.samplerate:g} samples/s) written to {target}"
    )
    return 0


def register(subparsers: Any) -> None:
    """Add the `decode` and `render` subcommands (CLI contract of `stack.cli`)."""
    p = subparsers.add_parser(
        "decode",
        help="decode a recorded CAN_RX waveform (.sr, .vcd, raw) into frames",
        description="Decode a CAN_RX waveform with a sample-domain bit receiver: hard sync after bus "
        "idle, resynchronisation with SJW, sampling at the sample point, destuffing and frame checks.",
    )
    p.add_argument("file", help="sigrok session (.sr), VCD, or raw file of one byte per sample")
    p.add_argument("--bitrate", type=_positive_float, required=True, help="nominal bit rate, bit/s")
    p.add_argument(
        "--channel", help="channel name, or 0-based index (#N when names are numbers; default CAN_RX or the only one)"
    )
    p.add_argument("--sample-point", type=parse_sample_point, default=87.5, help=SAMPLE_POINT_HELP + "; default 87.5")
    p.add_argument(
        "--sjw", type=float, default=None, help="synchronisation jump width in tq of 16 (default min(4, Phase_Seg2))"
    )
    p.add_argument("--samplerate", type=_positive_float, help="samples/s (required for raw files; resamples VCD)")
    p.add_argument(
        "--data-bitrate", type=_positive_float, help="CAN FD: data bit rate, bit/s (decodes FD frames, with BRS)"
    )
    p.add_argument(
        "--data-sample-point", type=parse_sample_point, default=75.0, help="CAN FD data phase: " + SAMPLE_POINT_HELP
    )
    p.add_argument("--no-retry", action="store_true", help="do not retry failed frames at other sample points")
    p.add_argument(
        "--json",
        action="store_true",
        help="one JSON object per frame per line (id as an integer; the table shows 0x-hex)",
    )
    p.set_defaults(func=_cmd_decode)

    r = subparsers.add_parser(
        "render",
        help="render frames (JSON lines) as a CAN_RX waveform (VCD or raw samples)",
        description="Render the frames listed (decode --json keys; t optional, back to back when "
        "missing) as a CAN_RX waveform.",
    )
    r.add_argument("frames", help="JSON-lines file of frames ('-' for stdin)")
    r.add_argument("--bitrate", type=_positive_float, required=True, help="bit rate, bit/s")
    r.add_argument("--samplerate", type=_positive_float, required=True, help="samples/s")
    r.add_argument("--data-bitrate", type=_positive_float, help="CAN FD: data bit rate of frames with BRS, bit/s")
    r.add_argument(
        "--sample-point",
        type=parse_sample_point,
        default=87.5,
        help="the transmitter's nominal sample point, where BRS switches to the data bit rate (87.5)",
    )
    r.add_argument(
        "--data-sample-point",
        type=parse_sample_point,
        default=75.0,
        help="its data sample point, where the CRC delimiter switches back (75)",
    )
    out = r.add_mutually_exclusive_group(required=True)
    out.add_argument("--vcd", help="write VCD (GTKWave, PulseView)")
    out.add_argument("--raw", help="write raw samples, one byte per sample")
    r.add_argument("--raw-bit", type=int, default=None, help="raw: recessive as 1 << BIT instead of 1")
    r.add_argument("--name", default="CAN_RX", help="VCD signal name (default CAN_RX)")
    r.add_argument("--drift", type=float, default=0.0, help="transmitter clock error, fraction (0.01 = 1 %% slow)")
    r.add_argument("--jitter", type=float, default=0.0, help="edge jitter, fraction of a bit (uniform)")
    r.add_argument("--seed", type=int, default=0, help="seed for the jitter")
    r.set_defaults(func=_cmd_render)
