"""Read a YAML or JSON document (a scene, a scenario) safely: bounded in size, in the nodes its
aliases expand to, and in the digits of its numbers; every refusal one line naming the file.

What a hostile or mistaken document can do to a plain ``yaml.safe_load``, and what is done here:

* **Alias bombs.** Nine anchors that each repeat the previous one nine times are a few hundred
  bytes and ten billion nodes once expanded; PyYAML builds them as shared references (cheap), but
  anything that walks the document afterwards (the variation parser, a deep copy, a dump)
  expands them. The node graph is measured, expanded, before anything is constructed: at most
  :data:`MAX_DOCUMENT_NODES` nodes, and an anchor used inside itself (a recursive alias) is
  refused.
* **Time.** The pure-Python parser reads about 0.25 MB/s; libyaml's (PyYAML's C binding, used
  where present) about 20 times that. Files are at most :data:`MAX_DOCUMENT_BYTES`.
* **YAML 1.1's surprises.** ``1:30:00`` is the integer 5400 in YAML 1.1 (base 60): here it is
  the string it looks like, so that a key expecting a number says so; ``1e3`` and ``-.5`` are
  numbers (as in YAML 1.2 and JSON), not strings. Merge keys (``<<: *base``)
  are honoured, their anchors kept in top-level ``x-...`` keys (dropped once read); a key given
  twice in one mapping is refused.
* **Huge integers.** Python refuses to convert more than 4,300 digits (``ValueError``); such a
  number is refused here naming its line.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

from ..errors import SonarsimError, check_input_file, shown

__all__ = ["MAX_ALIASES", "MAX_DOCUMENT_BYTES", "MAX_DOCUMENT_NODES", "MAX_NUMBER_DIGITS", "read_document"]

# A scene or scenario file is a few kilobytes; 20,000 objects written one a line take 2 MB. At
# most 4 MiB: libyaml composes an alias in about 1.5 microseconds, 4 MiB of them in about 1.5 s.
MAX_DOCUMENT_BYTES = 4 * 2**20
#: Nodes (mappings, lists, scalars) a document may hold, as written and once its aliases are
#: expanded. 20,000 objects of a scene take about 320,000; reading them takes about 3 s here,
#: and the variation draws of every frame walk them again.
MAX_DOCUMENT_NODES = 500_000
#: Aliases (``*name``) a YAML document may use: counted in the text before it is parsed, since
#: libyaml composes every alias before the expansion can be measured (a file of 800,000 of
#: them took seconds to refuse). Real scenes use a handful.
MAX_ALIASES = 100_000
#: Digits of an integer: beyond a float's range (309 digits) a number is refused anyway by the
#: key that reads it; beyond this it is not even converted (Python's own limit is 4,300).
MAX_NUMBER_DIGITS = 1_000

_MERGE_TAG = "tag:yaml.org,2002:merge"
#: Top-level keys of a YAML document that begin so hold anchors only and are dropped once read.
EXTENSION_PREFIX = "x-"
# An alias as YAML writes it: an asterisk starting a token, then the anchor's name (an upper
# bound: an asterisk so placed inside a quoted string counts too).
_ALIAS = re.compile(r"(?:^|(?<=[\s,\[{:-]))\*[^\s,\[\]{}]+")


def _yaml_loader(where: str):
    """A safe YAML loader class (libyaml's parser where installed) that refuses duplicate keys,
    counts the expanded nodes before constructing, reads no base-60 numbers and no integer of
    more than :data:`MAX_NUMBER_DIGITS` digits."""
    import yaml

    base = getattr(yaml, "CSafeLoader", None) or yaml.SafeLoader

    class Strict(base):
        # Own copies of the implicit resolvers, without YAML 1.1's base-60 integers and floats.
        yaml_implicit_resolvers = {
            first: [(tag, rx) for tag, rx in resolvers if tag not in ("tag:yaml.org,2002:int", "tag:yaml.org,2002:float")]
            for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
        }

        _resolved = 0

        def resolve(self, kind, value, implicit):
            # Called by the parser for every node it composes (an alias is not composed again):
            # counting here refuses a long document while it is read, not after (composing
            # costs about 6 microseconds a node, mostly in this Python call).
            self._resolved += 1
            if self._resolved > MAX_DOCUMENT_NODES:
                raise SonarsimError(f"{where}: the document holds more than {MAX_DOCUMENT_NODES:,} values; a scene "
                                    "or scenario holds far fewer")
            return super().resolve(kind, value, implicit)

        def get_single_data(self):
            node = self.get_single_node()
            if node is None:
                return None
            _check_expansion(node, where)
            return self.construct_document(node)

    Strict.add_implicit_resolver(
        "tag:yaml.org,2002:int",
        re.compile(r"""^(?:[-+]?0b[0-1_]+|[-+]?0[0-7_]+|[-+]?(?:0|[1-9][0-9_]*)|[-+]?0x[0-9a-fA-F_]+)$""", re.X),
        list("-+0123456789"))
    # Floats as YAML 1.2 reads them: 1e3 and -.5 are numbers (YAML 1.1 wants 1.0e+3 and reads
    # the others as strings, so that a key expecting a number said "got '1e3'").
    Strict.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*\.[0-9_]*|\.[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)?
                    |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", re.X),
        list("-+0123456789."))

    def mapping(loader, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == _MERGE_TAG:  # `<<: *base`: merged below, its keys may be overridden
                continue
            key = loader.construct_object(key_node, deep=deep)
            try:
                duplicate = key in seen
            except TypeError:  # an unhashable key: the base constructor says so
                break
            if duplicate:
                raise SonarsimError(f"{where}: the key {shown(key)} is given twice in one mapping "
                                    f"(line {key_node.start_mark.line + 1})")
            seen.add(key)
        return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)

    def integer(loader, node):
        digits = sum(c.isalnum() for c in str(node.value))
        if digits > MAX_NUMBER_DIGITS:
            raise SonarsimError(f"{where}: line {node.start_mark.line + 1}: an integer of {digits} digits; a number "
                                f"in a scene has at most {MAX_NUMBER_DIGITS}")
        return yaml.SafeLoader.construct_yaml_int(loader, node)

    Strict.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, lambda loader, node: mapping(loader, node))
    Strict.add_constructor("tag:yaml.org,2002:int", integer)
    Strict.construct_mapping = lambda self, node, deep=False: mapping(self, node, deep)
    return Strict


def _check_expansion(root, where: str, limit: int | None = None) -> int:
    """Count the nodes of a composed YAML document with its aliases expanded, without expanding
    them (each node's expanded size is computed once, from its children's).

    Returns
    -------
    int
        The expanded node count.

    Raises
    ------
    SonarsimError
        Beyond ``limit`` (default :data:`MAX_DOCUMENT_NODES`), naming the count reached and the
        line of the node being expanded, or an anchor used inside itself.
    """
    limit = MAX_DOCUMENT_NODES if limit is None else limit
    size: dict[int, int] = {}
    open_: set[int] = set()
    # Iterative post-order walk: documents nested thousands deep must not hit Python's recursion
    # limit here (the parser itself refuses what is too deep to construct).
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        value = node.value
        if not isinstance(value, list):  # a scalar
            size[key] = 1
            continue
        if done:
            open_.discard(key)
            total = 1
            for child in value:
                if isinstance(child, tuple):  # a mapping's (key, value) pair
                    total += size[id(child[0])] + size[id(child[1])]
                else:
                    total += size[id(child)]
            if total > limit:
                raise SonarsimError(
                    f"{where}: line {node.start_mark.line + 1}: the document expands to more than {limit:,} values "
                    "(its aliases repeat what their anchors hold); a scene or scenario holds far fewer")
            size[key] = total
            continue
        if key in size:
            continue
        if key in open_:
            raise SonarsimError(f"{where}: line {node.start_mark.line + 1}: an anchor is used inside itself "
                                "(a recursive alias); a scene or scenario is a tree")
        open_.add(key)
        stack.append((node, True))
        for child in value:
            for part in (child if isinstance(child, tuple) else (child,)):
                part_key = id(part)
                if part_key in open_:
                    raise SonarsimError(f"{where}: line {part.start_mark.line + 1}: an anchor is used inside itself "
                                        "(a recursive alias); a scene or scenario is a tree")
                if part_key not in size:
                    stack.append((part, False))
    return size[id(root)]


def _unique_pairs(pairs, where: str):
    """A JSON object's pairs as a dict, refusing a key given twice (JSON would keep the last)."""
    out = {}
    for k, v in pairs:
        if k in out:
            raise SonarsimError(f"{where}: the key {shown(k)} is given twice in one mapping")
        out[k] = v
    return out


def _json_integer(text: str, where: str) -> int:
    if len(text) > MAX_NUMBER_DIGITS:
        raise SonarsimError(f"{where}: an integer of {len(text)} digits; a number in a scene has at most "
                            f"{MAX_NUMBER_DIGITS}")
    return int(text)


def _count_json(value: Any, where: str) -> None:
    """Refuse a JSON document of more than :data:`MAX_DOCUMENT_NODES` values (JSON has no
    aliases: this is its size alone)."""
    count, stack = 0, [value]
    while stack:
        v = stack.pop()
        count += 1
        if count > MAX_DOCUMENT_NODES:
            raise SonarsimError(f"{where}: the document holds more than {MAX_DOCUMENT_NODES:,} values; a scene or "
                                "scenario holds far fewer")
        if isinstance(v, dict):
            stack.extend(v.values())
            count += len(v)
        elif isinstance(v, list):
            stack.extend(v)


def read_document(path: str | os.PathLike) -> Any:
    """Parse a YAML or JSON file (JSON by a ``.json`` suffix, YAML otherwise).

    Parameters
    ----------
    path : path-like
        A scene or scenario file.

    Returns
    -------
    object
        The document (mappings, lists, strings, numbers, booleans, None).

    Raises
    ------
    SonarsimError
        The file is missing, a directory, pipe or device, larger than
        :data:`MAX_DOCUMENT_BYTES`, not UTF-8 text, nested too deeply, expanding to more than
        :data:`MAX_DOCUMENT_NODES` values, holding a recursive alias or an integer of more than
        :data:`MAX_NUMBER_DIGITS` digits, not valid YAML/JSON, or gives a key twice in one
        mapping.
    """
    import yaml

    p = Path(path)
    size = check_input_file(p, "scene file").st_size
    if size > MAX_DOCUMENT_BYTES:
        raise SonarsimError(f"{p}: {size / 2**20:.0f} MiB is not a scene file (at most "
                            f"{MAX_DOCUMENT_BYTES // 2**20} MiB)")
    try:
        # utf-8-sig: a byte-order mark (Windows editors write one) is not part of the text.
        text = p.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SonarsimError(f"{p}: not UTF-8 text (byte {exc.start}): a scene file is YAML or JSON text") from None
    except OSError as exc:
        raise SonarsimError(f"{p}: cannot read the scene file: {exc.strerror or exc}") from None
    try:
        if p.suffix.lower() == ".json":
            doc = json.loads(text, object_pairs_hook=lambda pairs: _unique_pairs(pairs, str(p)),
                             parse_int=lambda s: _json_integer(s, str(p)))
            _count_json(doc, str(p))
            return doc
        aliases = sum(1 for _ in _ALIAS.finditer(text))
        if aliases > MAX_ALIASES:
            raise SonarsimError(f"{p}: {aliases:,} aliases (*name); a scene or scenario uses at most {MAX_ALIASES:,}")
        doc = yaml.load(text, Loader=_yaml_loader(str(p)))  # noqa: S506 - a SafeLoader subclass
        if isinstance(doc, dict):
            # Top-level keys named x-...: a place for anchors that merge keys and aliases use
            # (as Docker Compose's extension fields), dropped here; every other key is checked.
            doc = {k: v for k, v in doc.items() if not (isinstance(k, str) and k.startswith(EXTENSION_PREFIX))}
        return doc
    except json.JSONDecodeError as exc:
        raise SonarsimError(f"{p}: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        # A reader error (a control character) has no mark and its str() spans two lines.
        problem = getattr(exc, "problem", None) or getattr(exc, "reason", None) or str(exc)
        if isinstance(getattr(exc, "position", None), int) and not where:
            line = text.count("\n", 0, exc.position) + 1
            where = f" at line {line}, column {exc.position - (text.rfind(chr(10), 0, exc.position) + 1) + 1}"
            if isinstance(getattr(exc, "character", None), int):
                problem = f"{problem} (character #x{exc.character:04x})"
        problem = ' '.join(str(problem).split())
        if "nesting depth" in problem:  # libyaml's own limit (1,000 levels)
            raise SonarsimError(f"{p}: nested too deeply to be a scene file{where.replace(' at', ' (at', 1)})") from None
        raise SonarsimError(f"{p}: invalid YAML{where}: {problem}") from None
    except RecursionError:
        raise SonarsimError(f"{p}: nested too deeply to be a scene file") from None
