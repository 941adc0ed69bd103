"""Text files read as UTF-8, one rule for every reader of the project (det files, ground truth,
configs, fault plans, scenarios, topologies, calibration, homographies, point pairs, state
files): bytes that are not UTF-8 (a binary file, or text in another encoding) become the
reader's own typed error naming the file, the line and the byte offset of the first bad byte,
never a ``UnicodeDecodeError`` traceback.

A reader passes ``error``, which makes its exception from a :class:`NotText`; ``str(e)`` is
``<path>:<line>: <problem>`` for readers whose errors name a file and a line, ``e.problem`` the
same without the place for readers that say it their own way (``cam0.toml: line 3: ...``)::

    text = read_text(path, lambda e: TopologyError(str(e)))
"""
from __future__ import annotations

import codecs
import os
from collections.abc import Callable, Iterator
from pathlib import Path

from protocol.errors import DmttError

CHUNK = 1 << 16  # bytes read at a time while finding the first bad byte


class NotText(DmttError, ValueError):
    """The first bytes of ``path`` that are not UTF-8: ``byte`` at ``offset`` (from 0), on
    ``line`` (1-based, counting ``\\n``)."""

    def __init__(self, path: str | os.PathLike[str], line: int, offset: int, byte: int):
        self.path, self.line, self.offset, self.byte = Path(path), line, offset, byte
        super().__init__(f"{path}:{line}: {self.problem}")

    @property
    def problem(self) -> str:
        return (f"not UTF-8 text: byte 0x{self.byte:02x} at offset {self.offset} (a binary "
                "file, or another encoding)")


def read_text(path: str | os.PathLike[str], error: Callable[[NotText], Exception]) -> str:
    """The whole of ``path`` as UTF-8 text (newlines as ``Path.read_text`` gives them); bytes
    that are not UTF-8 raise ``error(NotText)``. ``OSError`` is the caller's to handle."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise error(first_bad_byte(path, e)) from None


def text_lines(path: str | os.PathLike[str], error: Callable[[NotText], Exception]
               ) -> Iterator[tuple[int, str]]:
    """``(line number, line)`` of ``path`` read as UTF-8 a line at a time (for files too long to
    hold as one string); bytes that are not UTF-8 raise ``error(NotText)`` when reading reaches
    them. ``OSError`` is the caller's to handle."""
    try:
        with open(path, encoding="utf-8") as fh:
            yield from enumerate(fh, start=1)
    except UnicodeDecodeError as e:
        raise error(first_bad_byte(path, e)) from None


def first_bad_byte(path: str | os.PathLike[str], cause: UnicodeDecodeError) -> NotText:
    """Where ``path``'s first bytes that are not UTF-8 are: the file is decoded again from the
    start, :data:`CHUNK` bytes at a time (a text file's decoder reports an offset within the
    block it was decoding, not within the file). ``cause`` describes them if the file has
    changed since and now decodes."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    offset, line = 0, 1  # of the first byte not decoded yet
    with open(path, "rb") as fh:
        while True:
            chunk = fh.read(CHUNK)
            data = decoder.getstate()[0] + chunk  # an unfinished character's bytes, then these
            try:
                decoder.decode(chunk, final=not chunk)
            except UnicodeDecodeError as e:
                return NotText(path, line + data.count(b"\n", 0, e.start), offset + e.start,
                               data[e.start])
            done = len(data) - len(decoder.getstate()[0])
            line += data.count(b"\n", 0, done)
            offset += done
            if not chunk:
                return NotText(path, 1, cause.start, cause.object[cause.start])
