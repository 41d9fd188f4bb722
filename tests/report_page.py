"""A report read back for tests: `Page` parses the HTML that `swarmraft report` writes."""

from __future__ import annotations

import html.parser


class Page(html.parser.HTMLParser):
    """What a test reads from a report: every tag with its attributes, the rows of each table
    (by id) as {data-col or header: text}, the key tables as {data-key: text}, the text of each
    element with an id, and the check list items as (level, text)."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.tables: dict[str, list[dict[str, str]]] = {}
        self.keys: dict[str, dict[str, str]] = {}
        self.by_id: dict[str, str] = {}
        self.checks: list[tuple[str, str]] = []
        self._table: str | None = None
        self._row: dict[str, str] | None = None
        self._key: str | None = None
        self._cell: str | None = None
        self._text: list[str] = []
        self._ids: list[tuple[str, str, int]] = []  # (id, tag, depth)
        self._id_text: dict[str, list[str]] = {}
        self._check: str | None = None
        self._depth = 0
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        self.tags.append((tag, a))
        if tag in ("img", "meta", "br", "link", "input"):
            return
        self._depth += 1
        if "id" in a:
            self._ids.append((a["id"], tag, self._depth))
            self._id_text[a["id"]] = []
        if tag == "table":
            self._table = a.get("id", "")
            self.tables.setdefault(self._table, [])
            self.keys.setdefault(self._table, {})
        elif tag == "tr" and self._table is not None:
            self._row = {}
            self._key = a.get("data-key")
        elif tag == "td" and self._row is not None:
            self._cell = a.get("data-col", "value")
            self._text = []
        elif tag == "li" and "data-level" in a:
            self._check = a["data-level"]
            self._text = []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("img", "meta", "br", "link", "input"):
            return
        if self._ids and self._ids[-1][1] == tag and self._ids[-1][2] == self._depth:
            self.by_id[self._ids[-1][0]] = "".join(self._id_text[self._ids[-1][0]])
            self._ids.pop()
        self._depth -= 1
        if tag == "td" and self._cell is not None and self._row is not None:
            self._row[self._cell] = "".join(self._text)
            self._cell = None
        elif tag == "tr" and self._row is not None and self._table is not None:
            if self._key is not None:
                self.keys[self._table][self._key] = self._row.get("value", "")
            elif self._row:
                self.tables[self._table].append(self._row)
            self._row = None
        elif tag == "table":
            self._table = None
        elif tag == "li" and self._check is not None:
            badge, _, text = "".join(self._text).strip().partition(" ")  # FAIL, WARN or OK first
            self.checks.append((self._check, text.strip()))
            self._check = None

    def handle_data(self, data: str) -> None:
        self._text.append(data)
        for ident, _, _ in self._ids:
            self._id_text[ident].append(data)
