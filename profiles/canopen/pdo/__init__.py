"""PDO: process data objects (CiA 301 7.2.2) — mapping, the shared configuration rules,
transmit PDOs and receive PDOs."""
