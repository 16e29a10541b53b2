"""A tiny document model shared by the PDF (typst) and HTML writers.

All text in the blocks is plain text (never markup): each writer escapes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

ParaKind = Literal["normal", "note", "strong", "pass", "fail", "warn"]


@dataclass
class Heading:
    text: str
    level: int = 1


@dataclass
class Para:
    text: str
    kind: ParaKind = "normal"


@dataclass
class Cell:
    text: str
    colspan: int = 1
    bold: bool = False


@dataclass
class Table:
    """A table: header rows (cells may span columns), body rows, per-column alignment."""

    header: list[list[Cell]]
    rows: list[list[Cell]]
    align: str  # one of "l", "c", "r" per column
    caption: str = ""
    footer_rows: int = 0  # last rows set apart (totals, RMS)

    @property
    def ncols(self) -> int:
        return len(self.align)


@dataclass
class KeyValue:
    """Two-column list of labels and values; ``mono`` values are set in a fixed-width font."""

    rows: list[tuple[str, str, bool]]


@dataclass
class Figure:
    name: str  # file stem, e.g. "residuals"
    png: bytes
    caption: str
    width: float = 1.0  # fraction of the text width


Block = Heading | Para | Table | KeyValue | Figure


@dataclass
class Report:
    """The certificate in memory: title, blocks in order, and the language."""

    lang: str
    title: str
    subtitle: str
    running_head: str
    blocks: list[Block] = field(default_factory=list)
    certificate_id: str = ""  # printed on every page (ISO/IEC 17025 7.8.2.1 b)
    draft: bool = False  # no issuing laboratory: title, running head and identifier say so

    @property
    def figures(self) -> list[Figure]:
        """The figures, in order."""
        return [b for b in self.blocks if isinstance(b, Figure)]

    def add(self, *blocks: Block) -> None:
        self.blocks.extend(blocks)
