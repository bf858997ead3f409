"""OpenIGTLink framing: the 58-byte header, its checks, the body CRC, and decoding a body.

pyigtl packs and unpacks message *contents* (we keep it for that); this module decides
what a peer's bytes may do before pyigtl sees them. pyigtl's own receive path checks
nothing: it never verifies the CRC (``MessageBase.unpack`` ignores the header's CRC
field), trusts the declared body size (a client announcing 2^64 - 1 bytes makes it read
forever), and lets any exception of its unpackers escape.

Header (version 1 and 2, big-endian; http://openigtlink.org/protocols/v2_header.html)::

    H   version      1 or 2
    12s type         ASCII, NUL-padded ("TRANSFORM", "IMAGE", "STRING", ...)
    20s device name  ASCII, NUL-padded
    II  timestamp    seconds, fraction of a second (2^-32 s)
    Q   body size    bytes that follow the header
    Q   CRC-64       ECMA-182 polynomial over the body (pyigtl's ``CRC64``)
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from pyigtl.messages import CRC64, MessageBase, StringMessage, TransformMessage

from icenav.errors import IgtlProtocolError

__all__ = [
    "HEADER_SIZE",
    "Header",
    "decode_body",
    "parse_header",
]

HEADER_SIZE = MessageBase.IGTL_HEADER_SIZE
"""Bytes of an OpenIGTLink header (58)."""

_HEADER = struct.Struct(">H12s20sIIQQ")
_PRINTABLE = frozenset(range(0x20, 0x7F))
_TRANSFORM_BODY = 48  # 12 big-endian float32


@dataclass(frozen=True)
class Header:
    """A checked OpenIGTLink header."""

    version: int
    """Header version (1 or 2)."""
    type: str
    """Message type, e.g. "STRING" (printable ASCII, <= 12 characters)."""
    device: str
    """Device name (printable ASCII, <= 20 characters; "" if it was not printable)."""
    timestamp_s: float
    """Time stamp (s since 1970)."""
    body_size: int
    """Bytes of the body that follows (bytes)."""
    crc: int
    """CRC-64 of the body as the sender computed it."""


def _ascii_field(raw: bytes) -> str | None:
    text = raw.rstrip(b"\0")
    if not text or not all(b in _PRINTABLE for b in text):
        return None
    return text.decode("ascii")


def parse_header(data: bytes, max_body_bytes: int) -> Header:
    """Check and parse the first :data:`HEADER_SIZE` bytes of a message.

    Raises
    ------
    IgtlProtocolError
        An unknown header version, a type that is not printable ASCII, or a body larger
        than ``max_body_bytes``: the stream cannot be trusted after such a header, and the
        caller closes the connection.
    """
    if len(data) < HEADER_SIZE:
        raise IgtlProtocolError(f"header of {len(data)} bytes, expected {HEADER_SIZE}")
    version, mtype, device, sec, frac, size, crc = _HEADER.unpack_from(data)
    if version not in (1, 2):
        raise IgtlProtocolError(f"header version {version} is not 1 or 2", kind="bad_header")
    type_text = _ascii_field(mtype)
    if type_text is None:
        raise IgtlProtocolError(f"message type {mtype!r} is not printable ASCII", kind="bad_header")
    if size > max_body_bytes:
        raise IgtlProtocolError(
            f"{type_text} message announces a body of {size} bytes; at most "
            f"{max_body_bytes} bytes are accepted",
            kind="oversize",
        )
    return Header(
        version=version,
        type=type_text,
        device=_ascii_field(device) or "",
        timestamp_s=sec + frac / 2.0**32,
        body_size=size,
        crc=crc,
    )


def _fields(header: Header) -> dict[str, Any]:
    return {
        "header_version": header.version,
        "message_type": header.type,
        "device_name": header.device,
        "timestamp": header.timestamp_s,
        "body_size": header.body_size,
    }


def decode_body(header: Header, body: bytes) -> StringMessage | TransformMessage:
    """Verify the body's CRC and decode a STRING or TRANSFORM message with pyigtl.

    Raises
    ------
    IgtlProtocolError
        ``kind`` says why: "bad_crc", "unknown_type" (any other type: icenav reads none),
        "bad_device" (a name that is not printable ASCII), "malformed" (a body that does
        not hold what its type needs: short, over-long string, unknown text encoding),
        "non_finite" (a NaN or inf in a TRANSFORM).
    """
    if len(body) != header.body_size:
        raise IgtlProtocolError(
            f"body of {len(body)} bytes, the header announced {header.body_size}",
            kind="malformed",
        )
    crc = CRC64(body)
    if crc != header.crc:
        raise IgtlProtocolError(
            f"{header.type} message CRC-64 {header.crc:#018x} does not match its body "
            f"({crc:#018x})",
            kind="bad_crc",
        )
    if not header.device:
        raise IgtlProtocolError("device name is empty or not printable ASCII", kind="bad_device")
    if header.type == "STRING":
        return _decode_string(header, body)
    if header.type == "TRANSFORM":
        return _decode_transform(header, body)
    raise IgtlProtocolError(f"message type {header.type!r} is not read", kind="unknown_type")


def _content(header: Header, body: bytes) -> bytes:
    """The content part of a body (after a version-2 extended header, before metadata)."""
    if header.version == 1:
        return body
    if len(body) < 12:
        raise IgtlProtocolError("version-2 body shorter than its extended header", "malformed")
    ext, meta_header, meta_body, _ = struct.unpack_from(">HHII", body)
    end = len(body) - meta_header - meta_body
    if ext < 12 or end < ext:
        raise IgtlProtocolError("version-2 extended header sizes exceed the body", "malformed")
    return body[ext:end]


def _decode_string(header: Header, body: bytes) -> StringMessage:
    content = _content(header, body)
    if len(content) < 4:
        raise IgtlProtocolError(f"STRING body of {len(content)} bytes (< 4)", "malformed")
    encoding, length = struct.unpack_from(">HH", content)
    if length != len(content) - 4:
        raise IgtlProtocolError(
            f"STRING announces {length} bytes of text and carries {len(content) - 4}",
            "malformed",
        )
    raw = content[4:]
    try:
        if encoding == MessageBase.IANA_CHARACTER_SET_ASCII:
            text = raw.decode("ascii")
        elif encoding == MessageBase.IANA_CHARACTER_SET_UTF8:
            text = raw.decode("utf-8")
        else:
            raise IgtlProtocolError(f"STRING encoding {encoding} is not ASCII (3) or UTF-8 (106)")
    except UnicodeDecodeError as exc:
        raise IgtlProtocolError(f"STRING text is not valid: {exc}", "malformed") from exc
    except IgtlProtocolError as exc:
        raise IgtlProtocolError(str(exc), "malformed") from exc
    message = StringMessage(text, timestamp=header.timestamp_s, device_name=header.device)
    message.header_version = header.version
    return message


def _decode_transform(header: Header, body: bytes) -> TransformMessage:
    content = _content(header, body)
    if len(content) != _TRANSFORM_BODY:
        raise IgtlProtocolError(
            f"TRANSFORM content of {len(content)} bytes, expected {_TRANSFORM_BODY}", "malformed"
        )
    values = struct.unpack(">12f", content)
    if not all(math.isfinite(v) for v in values):
        raise IgtlProtocolError("TRANSFORM holds a NaN or inf", kind="non_finite")
    message = TransformMessage(timestamp=header.timestamp_s, device_name=header.device)
    try:  # pyigtl also reads the version-2 metadata: anything it raises is a bad body
        message.unpack(_fields(header), body)
    except Exception as exc:  # noqa: BLE001 - pyigtl raises struct.error, ValueError, ...
        raise IgtlProtocolError(f"TRANSFORM body cannot be read: {exc}", "malformed") from exc
    message.matrix = np.asarray(message.matrix, dtype=np.float64)
    return message
