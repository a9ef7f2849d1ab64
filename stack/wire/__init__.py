"""The wire layer: identifiers and the Frame type, CRC-15 and bit stuffing (the encoder), and the
receiver's bit decoder (ISO 11898-1 frame format). It imports nothing else of `stack`."""
