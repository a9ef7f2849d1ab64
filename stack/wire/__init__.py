"""The wire layer: identifiers and the Frame type (CAN 2.0 and CAN FD), CRC-15 and bit stuffing
(the classical encoder, `coding`), the CAN FD coding of ISO 11898-1:2015 (`fd`: stuff count, fixed
stuff bits, CRC-17/21, two bit rates, worst-case lengths), and the receiver's bit decoder
(`decoder`). It imports nothing else of `stack`."""
