"""CAN_RX waveforms: render frames as a logic signal, and decode recorded signals into frames.

Level convention on the CAN_RX pin: 0 = dominant, 1 = recessive (as in `stack.wire.coding`).

The package follows the flow of a waveform:

- `stack.phy.waveform.capture` reads recordings (sigrok sessions, VCD, raw samples) into a
  `Capture`;
- `stack.phy.waveform.render` lays frames out as a waveform (`render_edges`, `render_samples`)
  and writes it (`write_vcd`, `write_raw`);
- `stack.phy.waveform.decode` receives frames from a waveform with a sample-domain bit receiver
  (`BitReceiver`, `decode_samples`, `decode_file`) into `RxRecord` s;
- `stack.phy.waveform.jsonl` turns records into JSON lines and JSON lines into frames;
- `stack.phy.waveform.levels` holds the level convention and the limits they share.

Every public name is importable from here (``from stack.phy.waveform import decode_file``).
"""

from __future__ import annotations

from stack.phy.waveform.capture import Capture, missing_input, read_capture, read_raw, read_sigrok, read_vcd
from stack.phy.waveform.decode import BitReceiver, RxRecord, decode_file, decode_samples
from stack.phy.waveform.jsonl import frames_from_jsonl, record_to_json
from stack.phy.waveform.levels import IDLE_BITS, MAX_RENDER_SAMPLES, MAX_SAMPLES_PER_BIT
from stack.phy.waveform.render import render_edges, render_samples, runs_to_raw, write_raw, write_vcd

__all__ = [
    "Capture",
    "RxRecord",
    "BitReceiver",
    "render_samples",
    "render_edges",
    "write_vcd",
    "write_raw",
    "runs_to_raw",
    "read_capture",
    "read_sigrok",
    "read_vcd",
    "read_raw",
    "decode_samples",
    "decode_file",
    "frames_from_jsonl",
    "record_to_json",
    "IDLE_BITS",
    "MAX_RENDER_SAMPLES",
    "MAX_SAMPLES_PER_BIT",
    "missing_input",
]
