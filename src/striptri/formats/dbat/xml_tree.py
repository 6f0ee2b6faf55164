"""The XML of DBAT files read safely: a minimal element tree with line numbers (:func:`parse_xml`).

Entity declarations and external entities are refused (InputError naming file and line), as
defusedxml does; the DBAT reader (:mod:`.reader`) walks the tree and cites its lines.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

from striptri.errors import InputError
from striptri.io.csvtable import read_input_bytes


@dataclass
class Element:
    tag: str
    attrib: dict
    line: int
    children: list = field(default_factory=list)
    text: str = ""

    def find(self, tag):
        for c in self.children:
            if c.tag == tag:
                return c
        return None

    def findall(self, tag):
        return [c for c in self.children if c.tag == tag]

    @property
    def value(self) -> str:
        return self.text.strip()


class _Refused(Exception):
    """Raised inside an expat handler: a construct the reader refuses, at a line."""

    def __init__(self, line: int, reason: str):
        super().__init__(reason)
        self.line, self.reason = line, reason


def parse_xml(path: Path) -> Element:
    """The element tree of an XML file, with line numbers. Linear in the size of the file: the
    character data of an element is collected in chunks and joined once at its end. DTD entity
    declarations and external entities are refused, as defusedxml does (a "billion laughs"
    document, or one that reads other files through entities): InputError naming file and line."""
    raw = read_input_bytes(path, "is a folder, not a DBAT XML file")
    parser = expat.ParserCreate()
    stack: list[tuple[Element, list[str]]] = []
    root: list[Element] = []

    def start(tag, attrib):
        el = Element(tag, dict(attrib), parser.CurrentLineNumber)
        if stack:
            stack[-1][0].children.append(el)
        else:
            root.append(el)
        stack.append((el, []))

    def end(tag):
        el, chunks = stack.pop()
        el.text = "".join(chunks)

    def chars(data):
        if stack:
            stack[-1][1].append(data)

    def entity_decl(name, is_parameter_entity, value, base, system_id, public_id, notation_name):
        kind = "parameter entity" if is_parameter_entity else "entity"
        raise _Refused(parser.CurrentLineNumber, f"the document declares the {kind} '{name}'; a DBAT file has no "
                                                 "entity declarations (refused: entity expansion can make a small "
                                                 "file enormous)")

    def unparsed_entity_decl(name, base, system_id, public_id, notation_name):
        raise _Refused(parser.CurrentLineNumber, f"the document declares the unparsed entity '{name}'; refused")

    def external_entity(context, base, system_id, public_id):
        raise _Refused(parser.CurrentLineNumber, f"the document refers to the external entity '{system_id}'; "
                                                 "refused (a DBAT file names its data files in <file> elements)")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    parser.EntityDeclHandler = entity_decl
    parser.UnparsedEntityDeclHandler = unparsed_entity_decl
    parser.ExternalEntityRefHandler = external_entity
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    try:
        parser.Parse(raw, True)
    except _Refused as exc:
        raise InputError(path, exc.line, exc.reason) from None
    except expat.ExpatError as exc:
        raise InputError(path, exc.lineno, f"not well-formed XML: {expat.ErrorString(exc.code)}") from None
    if not root:
        raise InputError(path, None, "no XML element")
    return root[0]
