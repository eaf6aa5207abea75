"""Message payloads that carry their own wire form, so that comm moves bytes only.

A comm backend sends Halo, Particles and numpy arrays field by field. Any other payload
type derives from `WirePayload`: it names a `wire_code`, packs itself into one uint8 array
(`to_wire`, given the destination rank) and rebuilds itself from it (`from_wire`); the
class registers with `@codec` when its module is imported (the backend that makes such
payloads imports it on both sides). Comm asks `encode` / `decode` and never imports a
compute module.
"""
from __future__ import annotations

import numpy as np

_CODECS: dict = {}


class WirePayload:
    """Base of payloads with a wire codec of their own."""

    wire_code = 0

    def nbytes(self) -> int:
        """Bytes the message itself moves."""
        raise NotImplementedError

    def to_wire(self, dest: int) -> np.ndarray:
        raise NotImplementedError

    @classmethod
    def from_wire(cls, buf: np.ndarray) -> "WirePayload":
        raise NotImplementedError


def codec(cls):
    """Class decorator: `cls.wire_code` decodes to `cls`."""
    have = _CODECS.get(cls.wire_code)
    if have is not None and have is not cls:
        raise ValueError(f"wire code {cls.wire_code} is taken by {have.__name__}")
    _CODECS[cls.wire_code] = cls
    return cls


def encode(payload: WirePayload, dest: int) -> tuple[int, np.ndarray]:
    return payload.wire_code, payload.to_wire(dest)


def decode(code: int, buf: np.ndarray) -> WirePayload:
    cls = _CODECS.get(int(code))
    if cls is None:
        from .errors import CommError
        raise CommError(f"a message of wire code {int(code)}, which no payload type of this process decodes")
    return cls.from_wire(buf)


def payload_nbytes(payload) -> int:
    """Bytes of the numpy arrays a payload carries (Halo, Particles, array, None; a
    WirePayload says its own)."""
    if payload is None:
        return 0
    if isinstance(payload, WirePayload):     # e.g. a device edge: the rows move device to device
        return int(payload.nbytes())
    if isinstance(payload, np.ndarray):
        return int(payload.nbytes)
    if hasattr(payload, "__dict__"):
        return sum(int(v.nbytes) for v in vars(payload).values() if isinstance(v, np.ndarray))
    return 0
