"""Reading field logs: MCAP files in file order, up to a break.

A file cut short (a SIGKILLed recorder, a full disk, a copy interrupted) has no summary
or footer and may end inside a chunk. `read_messages` streams records from the start and
stops cleanly at the break; `LogReport.truncated` says whether one was met and where.
Folders are read file by file in name order (rotation names sort by time).
"""

from __future__ import annotations

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


def _read_file(path: Path, report: LogReport, topics: set[str] | None) -> Iterator[LogMessage]:
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str, int]] = {}
    report.files.append(str(path))
    with open(path, "rb") as f:
        reader = StreamReader(f, validate_crcs=True)
        records = reader.records
        while True:
            try:
                rec = next(records)
            except StopIteration:
                return
            except Exception as exc:  # EndOfFile, CRC, struct and decompression errors at the break
                reason = f"{path}: stopped at byte {f.tell()}: {type(exc).__name__} {exc}".strip()
                report.truncated.append(reason)
                log.warning("log ends early: %s", reason)
                return
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
