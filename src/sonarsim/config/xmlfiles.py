"""XML files from users (SDF worlds, Collada meshes): read with the standard library's parser,
refusing what makes a small file expand or reach elsewhere.

An SDF world or a ``.dae`` mesh comes from anywhere (a model downloaded with a world). A
document type declaration is where entities are declared, and entities are how a kilobyte of
XML expands to gigabytes or names a file to pull in: no SDF or Collada file needs one, so the
declaration itself is refused, before any entity is expanded. The file's size is checked before
it is read (:func:`read_xml`).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from ..errors import SonarsimError, check_input_file

__all__ = ["XmlFileError", "parse_xml", "read_xml", "local_name"]


class XmlFileError(SonarsimError):
    """An XML file is missing, too large, malformed or declares a document type."""


class _Refused(Exception):
    """Raised from inside expat's handlers: the parse stops at the declaration."""


def _refuse_doctype(*_args) -> None:
    raise _Refused("a document type declaration (<!DOCTYPE ...>)")


def _refuse_entity(*_args) -> None:
    raise _Refused("an entity declaration (<!ENTITY ...>)")


def parse_xml(data: bytes, source: str) -> ET.Element:
    """The root element of the XML document ``data``.

    Parameters
    ----------
    data : bytes
        The document (any encoding its declaration names).
    source : str
        The file it came from, for the messages.

    Returns
    -------
    xml.etree.ElementTree.Element

    Raises
    ------
    XmlFileError
        ``SOURCE: not well-formed XML (...)`` or ``SOURCE: ... is not read``: a document type or
        entity declaration, which no SDF or Collada file needs.
    """
    import xml.parsers.expat as expat

    builder = ET.TreeBuilder()
    parser = expat.ParserCreate()  # no namespace processing: tags as written (Collada's default namespace is an attribute)
    parser.buffer_text = True
    parser.StartElementHandler = builder.start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    # expat calls these as it meets the declarations, before expanding anything declared.
    parser.StartDoctypeDeclHandler = _refuse_doctype
    parser.EntityDeclHandler = _refuse_entity
    parser.UnparsedEntityDeclHandler = _refuse_entity
    parser.ExternalEntityRefHandler = _refuse_entity
    try:
        parser.Parse(data, True)
        return builder.close()
    except _Refused as exc:
        raise XmlFileError(f"{source}: holds {exc}, which sonarsim does not read (entities can expand a small "
                           "file without bound); remove it") from None
    except expat.ExpatError as exc:
        raise XmlFileError(f"{source}: not well-formed XML ({exc})") from None
    except AssertionError:  # TreeBuilder: no root element
        raise XmlFileError(f"{source}: no XML element in the file") from None


def read_xml(path: str | os.PathLike, what: str, max_bytes: int) -> ET.Element:
    """Read and parse an XML file after checking that it is a regular file of at most ``max_bytes``.

    Parameters
    ----------
    path : path-like
    what : str
        What the file should be, for the messages (``"SDF file"``).
    max_bytes : int
        The largest file read, bytes.

    Returns
    -------
    xml.etree.ElementTree.Element
        The root element.

    Raises
    ------
    XmlFileError
        As :func:`sonarsim.errors.check_input_file`, a file over ``max_bytes``, or as :func:`parse_xml`.
    """
    p = Path(path)
    try:
        st = check_input_file(p, what)
    except SonarsimError as exc:
        raise XmlFileError(str(exc)) from None
    if st.st_size > max_bytes:
        raise XmlFileError(f"{p}: the {what} is {st.st_size / 2**20:.3g} MiB; allowed: at most "
                           f"{max_bytes / 2**20:.3g} MiB")
    if st.st_size == 0:
        raise XmlFileError(f"{p}: the {what} is empty")
    try:
        with open(p, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as exc:
        raise XmlFileError(f"{p}: cannot read the {what}: {exc.strerror or exc}") from None
    if len(data) > max_bytes:  # grown since the stat
        raise XmlFileError(f"{p}: the {what} is over {max_bytes / 2**20:.3g} MiB")
    return parse_xml(data, str(p))


def local_name(element: ET.Element) -> str:
    """An element's tag without a namespace prefix (``c:mesh`` is ``mesh``)."""
    return element.tag.rsplit(":", 1)[-1]
