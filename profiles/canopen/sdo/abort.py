"""SDO abort codes (CiA 301 7.2.4.3.17, table "SDO abort codes") and the exception that carries
one from where an access is refused to the SDO server that sends the abort.

The names follow the standard's descriptions; `tests/profiles/canopen/test_sdo_abort.py` checks
every value against the ``canopen`` library's table (a second implementation).
"""

from __future__ import annotations

__all__ = ["SdoAbort", "ABORT_TEXT"] + [
    "TOGGLE_BIT",
    "TIMEOUT",
    "COMMAND",
    "BLOCK_SIZE",
    "SEQUENCE",
    "CRC",
    "OUT_OF_MEMORY",
    "UNSUPPORTED_ACCESS",
    "WRITE_ONLY",
    "READ_ONLY",
    "NO_OBJECT",
    "NOT_MAPPABLE",
    "PDO_LENGTH",
    "PARAMETER_INCOMPATIBLE",
    "INTERNAL_INCOMPATIBLE",
    "HARDWARE",
    "LENGTH_MISMATCH",
    "LENGTH_HIGH",
    "LENGTH_LOW",
    "NO_SUBINDEX",
    "INVALID_VALUE",
    "VALUE_HIGH",
    "VALUE_LOW",
    "MAX_BELOW_MIN",
    "RESOURCE",
    "GENERAL",
    "CANNOT_STORE",
    "LOCAL_CONTROL",
    "DEVICE_STATE",
    "NO_DICTIONARY",
    "NO_DATA",
]

TOGGLE_BIT = 0x0503_0000
TIMEOUT = 0x0504_0000
COMMAND = 0x0504_0001
BLOCK_SIZE = 0x0504_0002
SEQUENCE = 0x0504_0003
CRC = 0x0504_0004
OUT_OF_MEMORY = 0x0504_0005
UNSUPPORTED_ACCESS = 0x0601_0000
WRITE_ONLY = 0x0601_0001
READ_ONLY = 0x0601_0002
NO_OBJECT = 0x0602_0000
NOT_MAPPABLE = 0x0604_0041
PDO_LENGTH = 0x0604_0042
PARAMETER_INCOMPATIBLE = 0x0604_0043
INTERNAL_INCOMPATIBLE = 0x0604_0047
HARDWARE = 0x0606_0000
LENGTH_MISMATCH = 0x0607_0010
LENGTH_HIGH = 0x0607_0012
LENGTH_LOW = 0x0607_0013
NO_SUBINDEX = 0x0609_0011
INVALID_VALUE = 0x0609_0030
VALUE_HIGH = 0x0609_0031
VALUE_LOW = 0x0609_0032
MAX_BELOW_MIN = 0x0609_0036
RESOURCE = 0x060A_0023
GENERAL = 0x0800_0000
CANNOT_STORE = 0x0800_0020
LOCAL_CONTROL = 0x0800_0021
DEVICE_STATE = 0x0800_0022
NO_DICTIONARY = 0x0800_0023
NO_DATA = 0x0800_0024

ABORT_TEXT: dict[int, str] = {
    TOGGLE_BIT: "toggle bit not alternated",
    TIMEOUT: "SDO protocol timed out",
    COMMAND: "client/server command specifier not valid or unknown",
    BLOCK_SIZE: "invalid block size (block mode only)",
    SEQUENCE: "invalid sequence number (block mode only)",
    CRC: "CRC error (block mode only)",
    OUT_OF_MEMORY: "out of memory",
    UNSUPPORTED_ACCESS: "unsupported access to an object",
    WRITE_ONLY: "attempt to read a write only object",
    READ_ONLY: "attempt to write a read only object",
    NO_OBJECT: "object does not exist in the object dictionary",
    NOT_MAPPABLE: "object cannot be mapped to the PDO",
    PDO_LENGTH: "the number and length of the objects to be mapped would exceed the PDO length",
    PARAMETER_INCOMPATIBLE: "general parameter incompatibility reason",
    INTERNAL_INCOMPATIBLE: "general internal incompatibility in the device",
    HARDWARE: "access failed due to a hardware error",
    LENGTH_MISMATCH: "data type does not match, length of service parameter does not match",
    LENGTH_HIGH: "data type does not match, length of service parameter too high",
    LENGTH_LOW: "data type does not match, length of service parameter too low",
    NO_SUBINDEX: "sub-index does not exist",
    INVALID_VALUE: "invalid value for parameter (download only)",
    VALUE_HIGH: "value of parameter written too high (download only)",
    VALUE_LOW: "value of parameter written too low (download only)",
    MAX_BELOW_MIN: "maximum value is less than minimum value",
    RESOURCE: "resource not available: SDO connection",
    GENERAL: "general error",
    CANNOT_STORE: "data cannot be transferred or stored to the application",
    LOCAL_CONTROL: "data cannot be transferred or stored to the application because of local control",
    DEVICE_STATE: "data cannot be transferred or stored to the application because of the present device state",
    NO_DICTIONARY: "object dictionary dynamic generation fails or no object dictionary is present",
    NO_DATA: "no data available",
}


class SdoAbort(Exception):
    """An access refused with an SDO abort code (CiA 301 7.2.4.3.17); ``why`` says in words
    which rule refused it (for logs and for the local API, which raises it too)."""

    def __init__(self, code: int, why: str = "") -> None:
        self.code = code
        self.why = why
        super().__init__(code, why)

    def __str__(self) -> str:
        text = f"SDO abort 0x{self.code:08X} ({ABORT_TEXT.get(self.code, 'unknown abort code')})"
        return f"{text}: {self.why}" if self.why else text
