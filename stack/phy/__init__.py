"""The physical layer: bit timing, synchronisation and CAN_RX waveforms (render and decode). It
imports only `stack.wire`."""
