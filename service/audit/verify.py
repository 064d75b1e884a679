"""Verify an audit file: MCAP framing and CRCs, then the hash chain.

The scanner reads the MCAP records itself (opcode, length, body) rather than
through a high-level reader so that it can say *where* a file is damaged (byte
offset, record index, log time, channel) and tell a file cut short by a crash
(no footer, possibly a partial last record) from one that was edited.

Exit codes (docs/audit.md): 0 intact, 1 broken or edited, 2 intact but
unfinished. With ``head``, a chain that does not end at that SHA-256 is broken.

A file is complete when it ends with a footer record and the closing magic; a
record whose length runs past the end of a complete file was damaged (broken), it
was not cut short by a crash (unfinished): a crash never writes the footer.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from enum import IntEnum
from io import BytesIO
from pathlib import Path
from typing import Any, Iterator

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Schema
from mcap.stream_reader import get_chunk_data_stream

from schemas.fast_json import loads

from ..errors import RegraspServiceError
from .chain import GENESIS, is_sha256_hex, record_digest
from .topics import KIND_CLOSE, KIND_OPEN, TOPIC_EVENTS

MAGIC = b"\x89MCAP0\r\n"
_RECORD_PREFIX = 9  # opcode (1) + length (8)
_FOOTER_CRC_PREFIX = _RECORD_PREFIX + 16  # footer bytes covered by the summary CRC
_KNOWN_OPCODES = {int(op) for op in Opcode}


class ExitCode(IntEnum):
    INTACT = 0
    BROKEN = 1
    UNFINISHED = 2


@dataclass(frozen=True)
class Where:
    """Location of a problem; any field may be unknown."""

    offset: int | None = None
    record_index: int | None = None
    log_time_ns: int | None = None
    channel: str | None = None

    def describe(self) -> str:
        parts = []
        if self.record_index is not None:
            parts.append(f"record #{self.record_index}")
        if self.channel is not None:
            parts.append(f"channel {self.channel}")
        if self.log_time_ns is not None:
            parts.append(f"log time {self.log_time_ns} ns")
        if self.offset is not None:
            parts.append(f"byte offset {self.offset}")
        return ", ".join(parts) if parts else "unknown location"


@dataclass
class AuditRecord:
    """One verified chain record."""

    index: int
    topic: str
    schema: str
    log_time_ns: int
    digest: str
    message: dict[str, Any] | None
    publish_time_ns: int = 0
    #: The message bytes as written (kept with ``keep_raw``).
    data: bytes = b""


@dataclass
class VerifyResult:
    status: str  # "intact" | "broken" | "unfinished"
    exit_code: int
    records: int  # chain records verified
    head: str | None  # digest of the last verified record
    job_id: str | None
    finished: bool  # footer and closing record present
    detail: str
    where: Where | None = None
    entries: list[AuditRecord] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "exit_code": self.exit_code,
            "records": self.records,
            "head": self.head,
            "job_id": self.job_id,
            "finished": self.finished,
            "detail": self.detail,
            "where": None
            if self.where is None
            else {
                "offset": self.where.offset,
                "record_index": self.where.record_index,
                "log_time_ns": self.where.log_time_ns,
                "channel": self.where.channel,
            },
        }


class _Broken(RegraspServiceError):
    def __init__(self, detail: str, where: Where, *, from_chain: bool = False) -> None:
        super().__init__(detail)
        self.detail = detail
        self.where = where
        self.from_chain = from_chain


class _Chain:
    """Running state of the chain check."""

    def __init__(self, keep: bool, keep_raw: bool = False) -> None:
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.seq = 0
        self.head = GENESIS
        self.job_id: str | None = None
        self.closed = False
        self.keep = keep
        self.keep_raw = keep_raw
        self.entries: list[AuditRecord] = []
        self.digests: list[str] = []
        self.last: Where | None = None
        #: A chunk whose CRC failed; reported unless the chain pins the edit down first.
        self.bad_crc: _Broken | None = None

    def message(self, msg: Message, offset: int) -> None:
        channel = self.channels.get(msg.channel_id)
        where = Where(offset, self.seq, msg.log_time, channel.topic if channel else None)
        if channel is None:
            raise _Broken(f"message on undeclared channel id {msg.channel_id}", where, from_chain=True)
        schema = self.schemas.get(channel.schema_id)
        schema_name = schema.name if schema is not None else ""
        if self.closed:
            raise _Broken("record after the closing record (appended after the job ended)", where, from_chain=True)
        try:
            body = loads(msg.data)
            link = body["audit"]
            seq, prev = int(link["seq"]), str(link["prev"])
        except (ValueError, KeyError, TypeError) as exc:
            raise _Broken(f"record is not a chained JSON message ({exc.__class__.__name__}: {exc})", where, from_chain=True) from None
        if seq != self.seq or msg.sequence != self.seq:
            raise _Broken(f"record carries sequence {seq} (MCAP {msg.sequence}), expected {self.seq}: "
                          "a record was removed, inserted or reordered", where, from_chain=True)
        if prev != self.head:
            last = self.last or where
            raise _Broken(
                f"record #{self.seq - 1} was edited after it was written: it hashes to {self.head[:16]}..., "
                f"but record #{self.seq} names {prev[:16]}... (or that link itself was edited)",
                Where(last.offset, self.seq - 1, last.log_time_ns, last.channel),
                from_chain=True,
            )
        if self.seq == 0:
            if channel.topic != TOPIC_EVENTS or body.get("kind") != KIND_OPEN:
                raise _Broken("the first record is not the audit.open event", where, from_chain=True)
            self.job_id = body.get("job_id")
        elif channel.topic == TOPIC_EVENTS and body.get("job_id") != self.job_id:
            raise _Broken(f"event names job {body.get('job_id')!r}, the file is job {self.job_id!r}", where, from_chain=True)
        digest = record_digest(self.seq, channel.topic, schema_name, msg.log_time, msg.publish_time, msg.data)
        if channel.topic == TOPIC_EVENTS and body.get("kind") == KIND_CLOSE:
            if (body.get("payload") or {}).get("records_before") != self.seq:
                raise _Broken("closing record counts a different number of records", where, from_chain=True)
            self.closed = True
        self.digests.append(digest)
        self.last = where
        if self.keep or self.keep_raw:
            self.entries.append(AuditRecord(self.seq, channel.topic, schema_name, msg.log_time, digest,
                                            body if self.keep else None, msg.publish_time,
                                            bytes(msg.data) if self.keep_raw else b""))
        self.head = digest
        self.seq += 1


def _records(stream: ReadDataStream, end: int) -> Iterator[tuple[int, int, int]]:
    """(opcode, start offset within the stream, body length) of records inside a chunk."""
    while stream.count < end:
        start = stream.count
        opcode = stream.read1()
        length = stream.read8()
        yield opcode, start, length


def _scan_chunk(chunk: Chunk, chain: _Chain, offset: int) -> None:
    where = Where(offset, chain.seq, chunk.message_start_time, None)
    try:
        stream, size = get_chunk_data_stream(chunk, validate_crc=False)
        data = stream.read(size) if size else b""
    except Exception as exc:  # corrupt compressed data
        raise _Broken(f"chunk cannot be decompressed ({exc})", where) from None
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc and chain.bad_crc is None:
        # Keep reading: the chain check then names the exact record that changed.
        chain.bad_crc = _Broken(
            f"chunk CRC mismatch (stored {chunk.uncompressed_crc:#010x}, computed {zlib.crc32(data):#010x}): "
            "bytes of the chunk starting at this record were changed",
            Where(offset, chain.seq, chunk.message_start_time, _first_topic(data, chain)),
        )
    if len(data) != chunk.uncompressed_size:
        raise _Broken("chunk size does not match its header", where)
    inner = ReadDataStream(BytesIO(data))
    try:
        for opcode, _start, length in _records(inner, len(data)):
            if opcode == Opcode.SCHEMA:
                schema = Schema.read(inner)
                chain.schemas[schema.id] = schema
            elif opcode == Opcode.CHANNEL:
                channel = Channel.read(inner)
                chain.channels[channel.id] = channel
            elif opcode == Opcode.MESSAGE:
                chain.message(Message.read(inner, length), offset)
            else:
                inner.read(length)
    except _Broken:
        raise
    except Exception as exc:
        raise _Broken(f"chunk content is malformed ({exc.__class__.__name__})", where) from None


def _first_topic(data: bytes, chain: _Chain) -> str | None:
    """Best-effort channel of the first message in (possibly damaged) chunk bytes."""
    try:
        inner = ReadDataStream(BytesIO(data))
        channels = dict(chain.channels)
        for opcode, _start, length in _records(inner, len(data)):
            if opcode == Opcode.CHANNEL:
                channel = Channel.read(inner)
                channels[channel.id] = channel
            elif opcode == Opcode.MESSAGE:
                msg = Message.read(inner, length)
                ch = channels.get(msg.channel_id)
                return ch.topic if ch else None
            else:
                inner.read(length)
    except Exception:
        return None
    return None


def _parse(opcode: int, body: bytes, length: int) -> Any:
    stream = ReadDataStream(BytesIO(body))
    if opcode == Opcode.HEADER:
        return Header.read(stream)
    if opcode == Opcode.FOOTER:
        return Footer.read(stream)
    if opcode == Opcode.SCHEMA:
        return Schema.read(stream)
    if opcode == Opcode.CHANNEL:
        return Channel.read(stream)
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, length)
    if opcode == Opcode.CHUNK:
        return Chunk.read(stream)
    if opcode == Opcode.DATA_END:
        return DataEnd.read(stream)
    return None  # indexes, statistics, metadata, attachments: not part of the chain


def _ends_at(chain: _Chain, head: str) -> bool:
    """The chain ends at ``head``: its last record, or the one the closing record seals.

    The closing record only seals the file (it follows the last event and counts
    the records), so a head stored just before ``close()`` names the same history.
    """
    if chain.head == head:
        return True
    return chain.closed and len(chain.digests) >= 2 and chain.digests[-2] == head


def _complete(data: bytes) -> bool:
    """The file ends with the closing magic, which the writer writes last, after the footer, on finishing.

    A file cut short by a crash never ends with it (the leading magic alone is not counted).
    """
    return len(data) > len(MAGIC) + _RECORD_PREFIX and data[-len(MAGIC):] == MAGIC


def verify(path: str | Path, head: str | None = None, *, keep_records: bool = False,
           keep_raw: bool = False) -> VerifyResult:
    """Check an audit file; see the module docstring for the verdicts.

    ``keep_records`` also returns the decoded records (for ``regrasp audit show``);
    ``keep_raw`` their bytes and times as written (to carry them into a new file).
    """
    if head is not None and not is_sha256_hex(head):
        raise ValueError(f"--head must be a SHA-256 in hex (64 hex digits), got {head!r}")
    data = Path(path).read_bytes()
    chain = _Chain(keep_records, keep_raw)
    complete = _complete(data)
    finished = False
    unfinished_note = ""

    def result(status: ExitCode, detail: str, where: Where | None = None) -> VerifyResult:
        return VerifyResult(
            status={0: "intact", 1: "broken", 2: "unfinished"}[int(status)],
            exit_code=int(status),
            records=chain.seq,
            head=chain.head if chain.seq else None,
            job_id=chain.job_id,
            finished=finished,
            detail=detail,
            where=where,
            entries=chain.entries,
        )

    if len(data) < len(MAGIC) or data[: len(MAGIC)] != MAGIC:
        if len(data) < len(MAGIC) and MAGIC.startswith(data):
            return result(ExitCode.UNFINISHED, "file holds no records yet (cut before the MCAP header)")
        return result(ExitCode.BROKEN, "not an MCAP file (bad magic)", Where(offset=0))

    pos = len(MAGIC)
    seen_header = False
    data_end_seen = False
    try:
        while True:
            if pos == len(data) and complete:
                raise _Broken("the records do not lead to the footer of a complete file: a length field was changed",
                              Where(pos, chain.seq))
            if pos == len(data):
                unfinished_note = "the file ends after a complete record, without the MCAP footer"
                break
            if len(data) - pos < _RECORD_PREFIX and complete:
                raise _Broken("the records do not lead to the footer of a complete file: a length field was changed",
                              Where(pos, chain.seq))
            if len(data) - pos < _RECORD_PREFIX:
                unfinished_note = f"the file ends inside a record header ({len(data) - pos} bytes at offset {pos})"
                break
            opcode, length = struct.unpack_from("<BQ", data, pos)
            if opcode not in _KNOWN_OPCODES:
                raise _Broken(f"unknown MCAP record opcode {opcode:#04x}: framing destroyed", Where(pos, chain.seq))
            end = pos + _RECORD_PREFIX + length
            if end > len(data) and complete:
                raise _Broken(f"record (opcode {opcode:#04x}) at offset {pos} claims {length} bytes, past the end of "
                              "a complete file: its length field was changed", Where(pos, chain.seq))
            if end > len(data):
                unfinished_note = (
                    f"the last record (opcode {opcode:#04x} at offset {pos}) is incomplete: "
                    f"{len(data) - pos - _RECORD_PREFIX} of {length} bytes"
                )
                break
            body = data[pos + _RECORD_PREFIX : end]
            try:
                record = _parse(opcode, body, length)
            except Exception as exc:
                raise _Broken(f"malformed MCAP record (opcode {opcode:#04x}): {exc.__class__.__name__}",
                              Where(pos, chain.seq)) from None
            if not seen_header:
                if opcode != Opcode.HEADER:
                    raise _Broken("the MCAP header record is missing", Where(pos))
                seen_header = True
            elif opcode == Opcode.HEADER:
                raise _Broken("a second MCAP header record", Where(pos, chain.seq))
            if isinstance(record, Chunk):
                if data_end_seen:
                    raise _Broken("a data chunk after the data section ended", Where(pos, chain.seq))
                _scan_chunk(record, chain, pos)
            elif isinstance(record, Schema):
                chain.schemas[record.id] = record
            elif isinstance(record, Channel):
                chain.channels[record.id] = record
            elif isinstance(record, Message):
                if data_end_seen:
                    raise _Broken("a message after the data section ended", Where(pos, chain.seq))
                chain.message(record, pos)
            elif isinstance(record, DataEnd):
                data_end_seen = True
                if record.data_section_crc != 0 and zlib.crc32(data[:pos]) != record.data_section_crc:
                    raise _Broken(
                        "data section CRC mismatch: bytes outside the message chunks (indexes, header) were changed",
                        Where(pos, chain.seq),
                    )
            elif isinstance(record, Footer):
                crc_start = record.summary_start or pos
                if record.summary_crc != 0:
                    computed = zlib.crc32(data[crc_start : pos + _FOOTER_CRC_PREFIX])
                    if computed != record.summary_crc:
                        raise _Broken("summary section CRC mismatch: the file's summary/index was changed",
                                      Where(crc_start, chain.seq))
                tail = data[end:]
                if tail != MAGIC:
                    if MAGIC.startswith(tail) and not complete:
                        unfinished_note = "the file ends inside the closing magic bytes"
                        break
                    raise _Broken("bytes after the MCAP footer (appended or edited)", Where(end, chain.seq))
                if not data_end_seen:
                    raise _Broken("footer without the data-end record", Where(pos, chain.seq))
                finished = True
                break
            pos = end
    except _Broken as broken:
        if chain.bad_crc is not None:
            if broken.from_chain:
                return result(ExitCode.BROKEN, f"MCAP CRC mismatch and {broken.detail}", broken.where)
            return result(ExitCode.BROKEN, chain.bad_crc.detail, chain.bad_crc.where)
        return result(ExitCode.BROKEN, broken.detail, broken.where)
    if chain.bad_crc is not None:
        return result(ExitCode.BROKEN, chain.bad_crc.detail, chain.bad_crc.where)

    if chain.seq == 0 and finished:
        return result(ExitCode.BROKEN, "a finished file with no audit records", Where(offset=len(MAGIC)))
    if finished and not chain.closed:
        return result(ExitCode.BROKEN, "the file is finished but its chain has no closing record "
                      "(records were removed and the file re-written)", Where(record_index=chain.seq))
    if head is not None and not _ends_at(chain, head.lower()):
        seen = ""
        if head.lower() in chain.digests:
            match = chain.digests.index(head.lower())
            if match is not None:
                seen = f"; {head[:16]}... is record #{match}, so records after it were added"
                if not finished:
                    seen += " (or the writer crashed after writing them but before the head was stored)"
        return result(
            ExitCode.BROKEN,
            f"the chain ends at {chain.head} (record #{chain.seq - 1}), not at the stored head {head}{seen}",
            Where(record_index=chain.seq - 1 if chain.seq else None),
        )
    if not finished:
        return result(ExitCode.UNFINISHED, f"chain intact over {chain.seq} records, but unfinished: {unfinished_note}")
    return result(ExitCode.INTACT, f"intact: {chain.seq} records, chain head {chain.head}")
