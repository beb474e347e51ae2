"""The syntax of ASAM MCD-2 MC (A2L) files: tokens, ``/begin`` ... ``/end`` blocks and
``/include``, read within stated bounds.

An A2L file is a tree of keyword blocks (``/begin MEASUREMENT ... /end MEASUREMENT``) whose
bodies are whitespace-separated words, quoted strings and nested blocks; ``/* */`` and ``//``
are comments; ``/include "FILE"`` splices another file in (ASAM MCD-2 MC 1.7, clause 3.2).  This
module builds that tree; :mod:`.a2l` reads what ambdaq needs from it.  Only the blocks in
``keep`` keep their words, so a 4 MB vendor file costs a few tens of MB.

Bounds: at most :data:`MAX_BYTES` read in all (the file and its includes), includes nested at
most :data:`MAX_INCLUDE_DEPTH` deep and blocks :data:`MAX_DEPTH` deep, and an include must be a
regular file (not a device, a FIFO or a directory).  Anything else is one
:class:`~ambdaq.errors.BadInputError` line naming the file and the line.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path

from ...errors import BadInputError

MAX_BYTES = 64 << 20  # the largest vendor A2L seen is 4 MB; 64 MB with its includes is refused, not read
MAX_INCLUDE_DEPTH = 8
MAX_DEPTH = 64

MAX_TOKEN = 1 << 20  # a word or string longer than 1 MB is no A2L's (a string of 50 MB once cost a DBC parser 10 GB)

# possessive runs: a long word or string is matched in one step, not one backtracking state per character
_TOKEN = re.compile(r"""
    (?P<space>\s++)
  | (?P<comment>/\*.*?\*/|//[^\n]*+)
  | (?P<string>"(?:[^"\\]++|\\.|"")*+")
  | (?P<word>(?:[^\s"/]++|/(?![*/]))++)
  | (?P<bad>.)
""", re.S | re.X)


class Text(str):
    """A quoted string of the file (its quotes removed), told apart from a word."""


@dataclass
class Block:
    """One ``/begin KEYWORD ... /end KEYWORD`` block: its words and strings in order, and its
    nested blocks (by keyword, in order)."""

    keyword: str
    line: int
    source: Path
    items: list[str] = field(default_factory=list)
    blocks: list["Block"] = field(default_factory=list)

    def children(self, keyword: str) -> list["Block"]:
        return [b for b in self.blocks if b.keyword == keyword]

    def child(self, keyword: str) -> "Block | None":
        for b in self.blocks:
            if b.keyword == keyword:
                return b
        return None

    def walk(self, keyword: str):
        """Every block of ``keyword`` below this one, depth first."""
        for b in self.blocks:
            if b.keyword == keyword:
                yield b
            yield from b.walk(keyword)

    def where(self) -> str:
        return f"{self.source}: line {self.line}"


def _unquote(text: str) -> Text:
    body = text[1:-1]
    return Text(body.replace('""', '"').replace('\\"', '"').replace("\\\\", "\\"))


def read_tree(path: Path, keep: frozenset[str]) -> tuple[Block, str]:
    """The block tree of the A2L file ``path`` (a root block holding its top-level blocks) and the
    SHA-256 of the file's bytes; only blocks whose keyword is in ``keep`` keep their words."""
    root = Block("", 0, path)
    reader = _Reader(keep)
    reader.read(path, root)
    return root, reader.sha256


class _Reader:
    def __init__(self, keep: frozenset[str]) -> None:
        self.keep = keep
        self.total = 0
        self.sha256 = ""  # of the top file

    def _text(self, path: Path, at: str) -> str:
        try:
            st = os.stat(path)
        except OSError as err:
            raise BadInputError(f"{at}cannot read {path}: {err.strerror or err}") from None
        if not stat.S_ISREG(st.st_mode):
            raise BadInputError(f"{at}{path} is not a regular file")
        self.total += st.st_size
        if self.total > MAX_BYTES:
            raise BadInputError(f"{at}{path}: the A2L and its includes exceed {MAX_BYTES >> 20} MB, more than ambdaq "
                                "reads (the largest vendor files are a few MB)")
        try:
            with open(path, "rb") as fh:  # no more than the bound, whatever the file grew to since stat
                data = fh.read(MAX_BYTES - self.total + st.st_size + 1)
        except OSError as err:
            raise BadInputError(f"{at}cannot read {path}: {err.strerror or err}") from None
        if len(data) > st.st_size:
            raise BadInputError(f"{at}{path}: it grew while being read")
        if not self.sha256:
            self.sha256 = hashlib.sha256(data).hexdigest()
        if data.startswith(b"\xef\xbb\xbf"):
            data = data[3:]
        try:
            return data.decode("utf-8")
        except UnicodeDecodeError:
            return data.decode("latin-1")  # A2L predates UTF-8; most vendor files are Latin-1

    def read(self, path: Path, root: Block, depth: int = 0, at: str = "") -> None:
        text = self._text(path, at)
        if not text.strip():
            raise BadInputError(f"A2L file {path}: empty")
        stack = [root]
        pending: str | None = None  # "/begin" or "/include", waiting for its operand
        line = 1
        last = 0
        for m in _TOKEN.finditer(text):
            kind = m.lastgroup
            if kind in ("space", "comment"):
                continue
            token = m.group()
            line += text.count("\n", last, m.start())
            last = m.start()
            if len(token) > MAX_TOKEN:
                raise BadInputError(f"A2L file {path}: line {line}: a {kind} of {len(token):,} characters "
                                    f"(at most {MAX_TOKEN:,} are read)")
            if kind == "bad":
                what = "an unterminated string" if token == '"' else ("an unterminated comment" if token == "/" else
                                                                      f"character {token!r}")
                raise BadInputError(f"A2L file {path}: line {line}: {what}")
            if pending == "/begin":
                if kind != "word":
                    raise BadInputError(f"A2L file {path}: line {line}: /begin needs a keyword, not {token!r}")
                if len(stack) > MAX_DEPTH:
                    raise BadInputError(f"A2L file {path}: line {line}: blocks nested over {MAX_DEPTH} deep")
                block = Block(token, line, path)
                stack[-1].blocks.append(block)
                stack.append(block)
                pending = None
                continue
            if pending == "/include":
                name = _unquote(token) if kind == "string" else token
                pending = None
                if depth >= MAX_INCLUDE_DEPTH:
                    raise BadInputError(f"A2L file {path}: line {line}: includes nested over {MAX_INCLUDE_DEPTH} deep")
                target = Path(name) if os.path.isabs(name) else path.parent / name
                self._include(target, stack, depth, f"A2L file {path}: line {line}: /include: ", path, line)
                continue
            if pending == "/end":
                if token != stack[-1].keyword or len(stack) == 1:
                    opened = f"{stack[-1].keyword} of line {stack[-1].line}" if len(stack) > 1 else "no block"
                    raise BadInputError(f"A2L file {path}: line {line}: /end {token} closes {opened}")
                stack.pop()
                pending = None
                continue
            if kind == "word" and token.lower() in ("/begin", "/end", "/include"):
                pending = token.lower()  # the keywords as written: /include and /INCLUDE alike
                continue
            block = stack[-1]
            if block.keyword in self.keep:
                block.items.append(_unquote(token) if kind == "string" else token)
        if pending is not None:
            raise BadInputError(f"A2L file {path}: line {line}: the file ends after {pending}")
        if len(stack) > 1:
            raise BadInputError(f"A2L file {path}: /begin {stack[-1].keyword} of line {stack[-1].line} has no /end")

    def _include(self, target: Path, stack: list[Block], depth: int, at: str, path: Path, line: int) -> None:
        """An included file's blocks go into the block the /include stands in."""
        if target.suffix.lower() == ".aml" and not target.exists():
            return  # the A2ML grammar of IF_DATA: ambdaq reads the XCP blocks it knows without it
        sub = Block("", line, path)
        self.read(target, sub, depth + 1, at)
        stack[-1].blocks.extend(sub.blocks)
        if stack[-1].keyword in self.keep:
            stack[-1].items.extend(sub.items)
