"""The simulated bus: a deterministic discrete-event driver for controllers (arbitration,
delivery, statistics, traces), the bit-level replay of attempts that can go wrong, and fault
injection. It imports `stack.controller` and `stack.wire`."""
