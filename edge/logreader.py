"""Reading field logs: MCAP files in file order, up to a break.

A file cut short (a SIGKILLed recorder, a full disk, a copy interrupted) has no summary
or footer and may end inside a chunk. `read_messages` streams records from the start and
stops cleanly at the break; `LogReport.truncated` says whether one was met and where. A
damaged chunk (bad CRC, data that does not decompress) costs that chunk only: it is listed
in `LogReport.corrupt` and reading goes on with the next record.
Folders are read file by file in name order (rotation names sort by time).
"""

from __future__ import annotations

import io
import logging
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from mmatch.errors import ParseError

log = logging.getLogger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class LogMessage:
    """One logged message. log_time_ns orders them; publish_time_ns is the data's stamp."""

    topic: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    encoding: str
    schema: str
    file: str


@dataclass
class LogReport:
    """What reading found: files, messages, and where it stopped early."""

    files: list[str] = field(default_factory=list)
    messages: int = 0
    truncated: list[str] = field(default_factory=list)  # "file: reason" per file cut short
    corrupt: list[str] = field(default_factory=list)    # "file: what at byte n" per damaged record skipped
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)


def is_mcap(path: str | Path) -> bool:
    """True when `path` is a file starting with the MCAP magic."""
    try:
        with open(path, "rb") as f:
            return f.read(8) == MCAP_MAGIC
    except OSError:
        return False


def log_files(path: str | Path) -> list[Path]:
    """The MCAP files of a log: the file itself, or a folder's *.mcap in name order."""
    p = Path(path)
    if p.is_dir():
        files = sorted(p.glob("*.mcap"))
        if not files:
            raise ParseError(f"{p}: no *.mcap files")
        return files
    if not p.exists():
        raise ParseError(f"{p}: no such file")
    if not is_mcap(p):
        raise ParseError(f"{p}: not an MCAP file")
    return [p]


_RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length
#: after a record whose length cannot be right, look this far ahead for the next good chunk
RESYNC_BYTES = 64 * 1024 * 1024


def _parse(cls, content: bytes, *args):
    from mcap.data_stream import ReadDataStream

    return cls.read(ReadDataStream(io.BytesIO(content)), *args)


def _summary(path: Path) -> tuple[dict, dict]:
    """Schemas and channels from a finished file's summary (so messages after a corrupt
    chunk that held their channel record still resolve); empty when there is none."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # no footer, no summary: the stream reading below is all there is
        return {}, {}
    if summary is None:
        return {}, {}
    return ({i: s.name for i, s in summary.schemas.items()},
            {i: (c.topic, c.message_encoding, c.schema_id) for i, c in summary.channels.items()})


def _resync(f, start: int, end: int) -> int | None:
    """File offset of the next chunk record that parses and passes its CRC, after `start`."""
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk

    f.seek(start)
    window = f.read(min(end - start, RESYNC_BYTES))
    at = window.find(b"\x06")
    while at >= 0:
        if at + 9 <= len(window):
            _, length = _RECORD_HEAD.unpack_from(window, at)
            if 0 < length <= len(window) - at - 9:
                try:
                    breakup_chunk(_parse(Chunk, window[at + 9:at + 9 + length]), validate_crc=True)
                    return start + at
                except Exception:
                    pass
        at = window.find(b"\x06", at + 1)
    return None


def _read_file(path: Path, report: LogReport, topics: set[str] | None) -> Iterator[LogMessage]:
    """Records one by one: a chunk that fails its CRC or does not decompress costs that chunk
    (report.corrupt) and reading goes on with the next record; a record whose length runs past
    the end is a break (report.truncated), after which the next good chunk is looked for."""
    from mcap.opcode import Opcode
    from mcap.records import Channel, Chunk, Message, Metadata, Schema
    from mcap.stream_reader import breakup_chunk

    schemas, channels = _summary(path)
    report.files.append(str(path))
    size = path.stat().st_size

    def note(kind: list[str], offset: int, what: str) -> None:
        reason = f"{path}: {what} at byte {offset}"
        kind.append(reason)
        log.warning("log %s: %s", "ends early" if kind is report.truncated else "damaged", reason)

    in_summary = False
    with open(path, "rb") as f:
        if f.read(8) != MCAP_MAGIC:
            note(report.truncated, 0, "no MCAP magic")
            return
        while True:
            offset = f.tell()
            head = f.read(_RECORD_HEAD.size)
            if not head:
                note(report.truncated, offset, "no footer (file cut short)")
                return
            if len(head) < _RECORD_HEAD.size:
                note(report.truncated, offset, "stopped inside a record header")
                return
            opcode, length = _RECORD_HEAD.unpack(head)
            if length > size - f.tell():
                note(report.truncated, offset, f"record of {length} bytes runs past the end")
                nxt = _resync(f, offset + 1, size)
                if nxt is None:
                    return
                note(report.corrupt, nxt, "reading again from the next good chunk")
                f.seek(nxt)
                continue
            content = f.read(length)
            if opcode == Opcode.FOOTER:
                if f.read(8) != MCAP_MAGIC:
                    note(report.truncated, f.tell(), "no closing magic")
                return
            if opcode == Opcode.DATA_END:
                in_summary = True  # copies of schemas and channels, indexes: nothing to replay
            if in_summary:
                continue
            try:
                if opcode == Opcode.CHUNK:
                    records = breakup_chunk(_parse(Chunk, content), validate_crc=True)
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA):
                    records = [_parse({Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
                                       Opcode.METADATA: Metadata}[opcode], content)]
                elif opcode == Opcode.MESSAGE:
                    records = [_parse(Message, content, length)]
                else:
                    continue
            except Exception as exc:  # CRC, decompression and struct errors inside the record
                note(report.corrupt, offset, f"corrupt {Opcode(opcode).name.lower() if opcode in set(Opcode) else opcode} "
                                             f"record skipped ({type(exc).__name__})")
                continue
            for rec in records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, rec.message_encoding, rec.schema_id)
                elif isinstance(rec, Metadata):
                    report.metadata[f"{path.name}:{rec.name}"] = dict(rec.metadata)
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    if ch is None:
                        continue
                    topic, enc, sid = ch
                    if topics is not None and topic not in topics and not any(
                            topic.startswith(t) for t in topics if t.endswith("/")):
                        continue
                    report.messages += 1
                    yield LogMessage(topic, rec.log_time, rec.publish_time, bytes(rec.data), enc,
                                     schemas.get(sid, ""), str(path))


def read_messages(path: str | Path, topics: list[str] | None = None,
                  report: LogReport | None = None) -> Iterator[LogMessage]:
    """Every message of a log (file or folder), in file order, up to any break.

    `topics`: only these (a topic ending in "/" matches as a prefix). `report` is filled as
    reading goes.
    """
    report = report if report is not None else LogReport()
    wanted = set(topics) if topics else None
    for p in log_files(path):
        try:
            yield from _read_file(p, report, wanted)
        except (OSError, struct.error) as exc:
            report.truncated.append(f"{p}: {exc}")
            log.warning("cannot read %s: %s", p, exc)
