"""Input files read safely: size, UTF-8, YAML limits, and schema checks with one-line messages.

Scenario files and robot data files go through the same reader. It refuses what could make
reading itself fail or run away, each with one line naming the file and, where there is one,
the line or the key:

* files larger than :data:`MAX_FILE_BYTES`, and files that are not UTF-8 text;
* YAML nested deeper than :data:`MAX_DEPTH`, aliases that refer to a collection containing
  them, and documents whose aliases expand to more than :data:`MAX_NODES` values ("billion
  laughs" bombs are refused after reading a few dozen lines, before any expansion);
* a key given twice in one mapping (YAML would keep the last one silently), named by its key
  path and both lines, and integers of more than 4300 digits (Python will not read them),
  named by their key path and line;
* mapping keys that are not strings (``1: a``).

:func:`check_schema` then validates the parsed document against a JSON schema in which a
``number`` or ``integer`` is a finite float (YAML's ``.nan`` and ``.inf``, and integers too
large for a float, are not numbers), and turns the first error into
:class:`~vtm_pin.InputError` with the key path, the value (as a short excerpt) and what is
allowed.
"""

from __future__ import annotations

import math
import os
import re
import stat
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import jsonschema
import yaml

from ..exceptions import InputError, excerpt

#: Largest payload mass [kg] of a robot data file's rated_payload. The bounds of the values
#: scenario and study files give are in their JSON Schemas (:mod:`vtm_pin.schemas`): generous
#: but finite, so that a value outside them is a typo (or 1e308), refused with its key.
MAX_MASS = 1.0e5

#: Largest input file read [bytes]; scenario and robot data files are a few kB.
MAX_FILE_BYTES = 1_000_000
#: Deepest nesting of YAML values (a scenario nests 8: ``events[].activate[].target.xyz[]``).
MAX_DEPTH = 32
#: Most values in a document once its aliases are expanded (a scenario has a few hundred).
MAX_NODES = 10_000


def open_regular(path: Path, error: type[InputError]) -> BinaryIO:
    """``path`` opened for reading in binary, after checking that it is a regular file.

    The file is opened without blocking and then checked (``fstat``), so that a named pipe, a
    device or a folder is refused at once instead of hanging the reader or reading forever.

    Raises:
        InputError: (as ``error``) The file is missing, cannot be opened, or is not a
            regular file; one line naming it and what it is.
    """
    source = excerpt(str(path), 200)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except (OSError, ValueError) as exc:  # ValueError: a NUL character in the path
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise error(source, "", f"cannot read the file ({reason})") from exc
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise error(source, "", f"is {_kind(mode)}, not a regular file; give a file")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def _kind(mode: int) -> str:
    """What a file that is not a regular file is, in words."""
    kinds = (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a named pipe (FIFO)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((word for test, word in kinds if test(mode)), "not a regular file")


def read_text(path: Path, error: type[InputError]) -> str:
    """The text of a file: at most :data:`MAX_FILE_BYTES`, strict UTF-8 (a BOM allowed).

    Raises:
        InputError: (as ``error``) The file cannot be read, is too large, or is not UTF-8
            text (the message gives the byte, its offset and line).
    """
    source = str(path)
    try:
        with open_regular(path, error) as file:
            data = file.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise error(source, "", f"cannot read the file ({exc.strerror or exc})") from exc
    if len(data) > MAX_FILE_BYTES:
        raise error(source, "", f"is larger than {MAX_FILE_BYTES} bytes; is it the right file?")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        hint = " (it starts like UTF-16)" if data[:2] in (b"\xff\xfe", b"\xfe\xff") else ""
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(
            source,
            "",
            f"is not UTF-8 text{hint}: byte 0x{data[exc.start]:02x} at offset {exc.start} "
            f"(line {line}); save it as UTF-8",
        ) from exc


def read_yaml(path: Path, error: type[InputError]) -> Any:
    """The parsed YAML document of a file, read within the limits above.

    Args:
        path: The file.
        error: Exception class raised for a bad file (``ScenarioError``, ``RobotDataError``).

    Raises:
        InputError: (as ``error``) The file cannot be read, is too large, is not UTF-8 text,
            is not valid YAML or breaks a limit; one line naming the file and the line.
    """
    source = str(path)
    text = read_text(path, error)
    loader = None
    try:
        loader = _LimitedLoader(text)  # a SafeLoader: builds plain data only
        node = loader.get_single_node()
        if node is None:  # an empty document
            return None
        _check_nodes(node, loader, source, error)
        return loader.construct_document(node)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = excerpt(exc.problem or exc.context or "", 120)
        raise error(source, "", f"not valid YAML{where}: {problem}") from exc
    except yaml.reader.ReaderError as exc:
        raise error(
            source,
            "",
            f"contains the character U+{int(exc.character):04X} at offset {exc.position}, "
            "which YAML does not allow (is it UTF-8 text?)",
        ) from exc
    except (yaml.YAMLError, RecursionError) as exc:
        raise error(source, "", f"not valid YAML: {excerpt(str(exc), 120)}") from exc
    finally:
        if loader is not None:
            loader.dispose()


def _check_nodes(node: Any, loader: Any, source: str, error: type[InputError]) -> None:
    """Refuse a key given twice in a mapping, and an integer too long for Python to read.

    YAML keeps the last of two equal keys without a word (a typo then silently changes a
    value), and Python refuses to read integers of more than 4300 digits; both are refused
    with the key path and the lines. Runs on the composed document, before it is built.
    """
    stack: list[tuple[list[Any], Any]] = [([], node)]
    seen: set[int] = set()  # nodes repeated by aliases are checked once
    while stack:
        path, node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            lines: dict[tuple[str, str], int] = {}
            for key, value in node.value:
                name = (key.tag, key.value) if isinstance(key, yaml.ScalarNode) else None
                line = key.start_mark.line + 1
                if name is not None and name in lines:
                    raise error(
                        source,
                        key_path([*path, key.value]),
                        f"is given twice, at lines {lines[name]} and {line}; keep one",
                    )
                if name is not None:
                    lines[name] = line
                stack.append((path, key))
                label = key.value if isinstance(key, yaml.ScalarNode) else "?"
                stack.append(([*path, label], value))
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(([*path, i], item) for i, item in enumerate(node.value))
        elif node.tag == "tag:yaml.org,2002:int":
            try:
                loader.construct_yaml_int(node)
            except ValueError as exc:  # Python reads integers of at most 4300 digits
                digits = sum(c.isdigit() for c in node.value)
                raise error(
                    source,
                    key_path(path),
                    f"an integer of {digits} digits at line {node.start_mark.line + 1}; "
                    "is it a typo?",
                ) from exc


class _LimitedLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing deep nesting, recursive aliases and alias bombs.

    The composer counts the values of the document as expanded: each node once, and each
    alias as the size of the node it repeats, so a bomb is refused as soon as the count passes
    :data:`MAX_NODES`, long before anything is expanded.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._count = 0
        self._sizes: dict[int, int] = {}  # id(node) -> values in the node, aliases expanded

    def compose_node(self, parent: Any, index: Any) -> Any:
        """The next node, counted; an alias counts as the size of the node it repeats."""
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            target = self.anchors.get(event.anchor)
            if target is not None:
                if id(target) not in self._sizes:
                    raise yaml.composer.ComposerError(
                        None,
                        None,
                        "an alias refers to a collection that contains it",
                        event.start_mark,
                    )
                self._add(self._sizes[id(target)], event.start_mark)
            return super().compose_node(parent, index)
        mark = self.peek_event().start_mark
        if self._depth >= MAX_DEPTH:
            raise yaml.composer.ComposerError(
                None, None, f"values nested deeper than {MAX_DEPTH} levels", mark
            )
        before = self._count
        self._add(1, mark)
        self._depth += 1
        node = super().compose_node(parent, index)
        self._depth -= 1
        self._sizes[id(node)] = self._count - before
        return node

    def _add(self, size: int, mark: Any) -> None:
        self._count += size
        if self._count > MAX_NODES:
            raise yaml.composer.ComposerError(
                None,
                None,
                f"more than {MAX_NODES} values (an alias counts as the values it repeats)",
                mark,
            )


# YAML 1.1 reads 1e-4 and 1.0e3 as text (a float needs a dot and a signed exponent); read
# them as numbers, as YAML 1.2 does, so that a scenario means what it looks like.
_LimitedLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def _is_number(checker: Any, instance: Any) -> bool:
    """JSON-schema ``number``: a finite float, or an int that converts to one."""
    if isinstance(instance, bool) or not isinstance(instance, (int, float)):
        return False
    try:
        return math.isfinite(float(instance))
    except OverflowError:
        return False


def _is_integer(checker: Any, instance: Any) -> bool:
    """JSON-schema ``integer``: a whole :func:`_is_number`.

    ``minimum`` and ``maximum`` apply to numbers only: an integer too large for a float would
    pass them unchecked.
    """
    whole = isinstance(instance, int) or (isinstance(instance, float) and instance.is_integer())
    return whole and _is_number(checker, instance)


_Validator = jsonschema.validators.extend(
    jsonschema.Draft202012Validator,
    type_checker=jsonschema.Draft202012Validator.TYPE_CHECKER.redefine_many(
        {"number": _is_number, "integer": _is_integer}
    ),
)


def number(
    low: float,
    high: float,
    description: str,
    *,
    exclusive_low: bool = False,
) -> dict[str, Any]:
    """Schema of a finite number in [low, high] (or (low, high] if ``exclusive_low``)."""
    bound = "exclusiveMinimum" if exclusive_low else "minimum"
    return {"type": "number", bound: low, "maximum": high, "description": description}


def check_schema(
    raw: Any,
    schema: Mapping[str, Any],
    source: str,
    error: type[InputError],
    root: str = "",
    valid: Mapping[str, Any] | None = None,
) -> None:
    """Validate a parsed document against ``schema``; raise on the first error, shallowest first.

    Args:
        raw: The parsed document.
        schema: JSON schema (draft 2020-12; ``number`` means a finite float).
        source: File name used in messages.
        error: Exception class raised.
        root: Key path of ``raw`` in its file ("" for a whole file, ``integrator`` for that
            part of a scenario).
        valid: A document known to pass ``schema`` (and not modified since). Top-level values
            of ``raw`` equal to its own (the same object, or the same repr) are not checked
            nor walked again (a study's cases differ from their base in a few keys); the top
            level itself (required and unknown keys) always is.

    Raises:
        InputError: (as ``error``) naming the key path, the value and what is allowed.
    """
    top = valid is not None and _is_mapping(raw) and set(schema) <= _TOP_LEVEL
    # Over MAX_NODES values in all, the whole walk below refuses the document, as it would.
    if valid is not None and top and _size_beside(raw, valid) <= MAX_NODES:
        raw, schema, done = _prune(raw, valid, schema)
        if done:  # what differs from valid passes: no key left to check
            return
    _check_keys(raw, source, error, root)
    errors = sorted(
        _Validator(schema).iter_errors(raw),
        key=lambda e: (len(e.absolute_path), [str(p) for p in e.absolute_path]),
    )
    if not errors:
        return
    found = _most_specific(errors[0])
    path: list[Any] = [root] if root else []
    path += list(found.absolute_path)
    if found.validator == "additionalProperties" and isinstance(found.instance, Mapping):
        known = found.schema.get("properties", {}) if isinstance(found.schema, Mapping) else {}
        path.append(sorted(str(k) for k in found.instance if k not in known)[0])
    raise error(source, key_path(path), _describe(found))


#: Schema keywords of a mapping under which ``check_schema(valid=...)`` may skip unchanged
#: values: each checks a value alone, or the keys, never one value against another.
_TOP_LEVEL = {"type", "additionalProperties", "required", "properties", "description"}


def _prune(raw: Any, valid: Any, schema: Any) -> tuple[Any, Any, bool]:
    """What of ``raw`` is left to check against ``schema``: (value, schema, whether it passes).

    Where the schema checks a mapping key by key (:data:`_TOP_LEVEL`), a value the same as
    ``valid``'s there (which passed that sub-schema) is dropped, its key no longer missing; so
    is a plain value that passes its plain sub-schema (:func:`_passes_alone`), and a mapping
    with nothing left to check; a mapping that differs is pruned in turn. Key paths, the
    sub-schemas met, and so the errors and their order are those of the whole check.
    """
    if _passes_alone(raw, schema):
        return raw, schema, True
    if not (
        _is_mapping(raw)
        and _is_mapping(schema)
        and set(schema) <= _TOP_LEVEL
        and schema.get("type", "object") == "object"
    ):
        return raw, schema, False
    known = valid if _is_mapping(valid) else {}
    properties, extra = schema.get("properties", {}), schema.get("additionalProperties")
    kept, inner = {}, {}
    for key, value in raw.items():
        if key in known and _same(value, known[key]):
            continue
        if key in properties:
            value, inner[key], done = _prune(value, known.get(key), properties[key])
        else:  # checked whole unless it passes whole
            done = isinstance(key, str) and _prune(value, known.get(key), extra)[2]
        if not done:
            kept[key] = value
    pruned = {**schema, "properties": {**properties, **inner}} if inner else dict(schema)
    if "required" in schema:
        pruned["required"] = [key for key in schema["required"] if key not in raw]
    return kept, pruned, not kept and not pruned.get("required")


#: Keywords of a plain value's schema that :func:`_passes_alone` decides.
_PLAIN = {"type", "minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "description"}


def _passes_alone(value: Any, schema: Any) -> bool:
    """Whether ``value`` surely passes a plain schema: a string, or a number within bounds.

    False when unsure (another keyword, another type, a value that fails): the validator
    then decides, and words the error.
    """
    if not _is_mapping(schema) or not set(schema) <= _PLAIN:
        return False
    kind = schema.get("type")
    if kind == "string":
        return isinstance(value, str)  # bounds apply to numbers only
    if not (kind == "number" and _is_number(None, value)) and not (
        kind == "integer" and _is_integer(None, value)
    ):
        return False
    low, high = schema.get("minimum", -math.inf), schema.get("maximum", math.inf)
    above = schema.get("exclusiveMinimum", -math.inf)
    below = schema.get("exclusiveMaximum", math.inf)
    return bool(low <= value <= high and above < value < below)


def _same(value: Any, known: Any) -> bool:
    """Whether a value is the known one: the same object, or the same repr.

    repr, not ==: 0 == False and 1 == 1.0, but the schema tells them apart.
    """
    return value is known or repr(value) == repr(known)


def _size_beside(raw: Mapping[str, Any], valid: Mapping[str, Any]) -> int:
    """:func:`_size` of ``raw``; the values it shares with ``valid`` (same objects) from a memo."""
    sizes = _VALID_SIZES.get(id(valid))
    if sizes is None or sizes[0] is not valid:
        if len(_VALID_SIZES) >= 16:
            _VALID_SIZES.clear()
        counts = {key: _size(value) for key, value in valid.items() if isinstance(key, str)}
        sizes = _VALID_SIZES[id(valid)] = (valid, counts)
    return 1 + sum(
        sizes[1][key] if key in valid and value is valid[key] else _size(value)
        for key, value in raw.items()
        if isinstance(key, str)
    )


#: Value counts of the top-level values of documents known to pass (``check_schema``'s
#: ``valid``), by the document's id (the document is kept, so that the id stays its own):
#: a study's cases are checked against one base.
_VALID_SIZES: dict[int, tuple[Mapping[str, Any], dict[str, int]]] = {}


def key_path(parts: Sequence[Any]) -> str:
    """``events[0].lock`` from ``["events", 0, "lock"]``; names are cut to short excerpts."""
    out = ""
    for part in parts:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{excerpt(part)}" if out else excerpt(part)
    return out


def _check_keys(raw: Any, source: str, error: type[InputError], root: str) -> None:
    """Refuse mapping keys that are not strings (YAML reads ``1:`` and ``yes:`` as numbers)."""
    for path, value in _walk(raw, [root] if root else [], source, error):
        if isinstance(value, Mapping):
            for key in value:
                if not isinstance(key, str):
                    raise error(
                        source,
                        key_path(path),
                        f"key {excerpt(key)} ({type(key).__name__}) is not a name: quote it "
                        f"('{excerpt(str(key))}')",
                    )


def _is_mapping(value: Any) -> bool:
    """isinstance(value, Mapping), a plain dict (parsed YAML, schemas) answered at once."""
    return type(value) is dict or isinstance(value, Mapping)


def _size(raw: Any) -> int:
    """How many values :func:`_walk` visits in a document (without building key paths)."""
    stack, seen = [raw], 0
    while stack:
        value = stack.pop()
        seen += 1
        if _is_mapping(value):
            stack.extend(v for k, v in value.items() if isinstance(k, str))
        elif isinstance(value, list):
            stack.extend(value)
    return seen


def _walk(
    raw: Any, root: list[Any], source: str, error: type[InputError]
) -> Iterator[tuple[list[Any], Any]]:
    """Every (key path, value) of a document, depth first, at most :data:`MAX_NODES` of them."""
    stack = [(root, raw)]
    seen = 0
    while stack:
        path, value = stack.pop()
        seen += 1
        if seen > MAX_NODES:
            raise error(source, key_path(root), f"has more than {MAX_NODES} values")
        yield path, value
        if isinstance(value, Mapping):
            stack.extend(([*path, k], v) for k, v in value.items() if isinstance(k, str))
        elif isinstance(value, list):
            stack.extend(([*path, i], v) for i, v in enumerate(value))


def _most_specific(error: jsonschema.ValidationError) -> jsonschema.ValidationError:
    """For a ``oneOf`` error, the error of the alternative that matches the value's type."""
    while error.validator == "oneOf" and error.context:
        relevant = [e for e in error.context if e.validator != "type" or e.relative_path]
        if not relevant:
            break
        error = max(relevant, key=lambda e: len(e.relative_path))
    return error


_TYPE_WORDS = {
    "number": "a number",
    "integer": "an integer",
    "string": "a string",
    "boolean": "true or false",
    "array": "a list",
    "object": "a mapping",
}

_ALTERNATIVES = {
    "number": "a number",
    "array": "a list of numbers",
    "object": "a mapping of joint names to numbers",
    "string": "a string",
    "null": "null",
}


def _describe(error: jsonschema.ValidationError) -> str:
    """What is wrong and what is allowed, one line; values are cut to short excerpts."""
    schema: Mapping[str, Any] = error.schema if isinstance(error.schema, Mapping) else {}
    kind = str(error.validator)
    limit: Any = error.validator_value
    value: Any = error.instance
    shown = f"'{excerpt(value)}'" if isinstance(value, str) else excerpt(value)
    bounds = {"exclusiveMinimum": ">", "minimum": ">=", "maximum": "<=", "exclusiveMaximum": "<"}
    if kind in bounds:
        return f"{shown} must be {bounds[kind]} {limit:g}{_unit(schema)}"
    if kind == "type":
        return _describe_type(shown, value, limit, schema)
    if kind == "additionalProperties":
        return f"unknown key; allowed keys here: {', '.join(sorted(schema.get('properties', {})))}"
    if kind == "required":
        return error.message.replace(" is a required property", " is missing")
    if kind == "enum":
        return f"{shown} is not allowed; allowed values: {', '.join(str(x) for x in limit)}"
    if kind == "oneOf":
        words = [_ALTERNATIVES.get(str(alt.get("type")), "?") for alt in limit]
        return f"{shown} must be {', '.join(words[:-1])} or {words[-1]}"
    messages = {
        "minItems": "must list at least one entry" if limit == 1 else f"must list {limit} entries",
        "maxItems": f"must list at most {limit} entries",
        "minProperties": "must name at least one key" if limit == 1 else f"needs {limit} keys",
        "multipleOf": f"{shown} must be a whole number",
    }
    return messages.get(kind, f"breaks the rule '{kind}' of the schema")


def _describe_type(shown: str, value: Any, wanted: Any, schema: Mapping[str, Any]) -> str:
    """A value of the wrong type: NaN, inf and huge integers are numbers that are not finite."""
    numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
    if numeric and wanted == "integer" and isinstance(value, int):  # too large for a float
        bound = ("maximum", "<=") if value > 0 else ("minimum", ">=")
        if bound[0] in schema:
            return f"{shown} must be {bound[1]} {schema[bound[0]]}{_unit(schema)}"
    if numeric and wanted in ("number", "integer"):
        return f"{shown} is not a finite number"
    words = " or ".join(
        _TYPE_WORDS.get(str(w), str(w)) for w in (wanted if isinstance(wanted, list) else [wanted])
    )
    hint = f" ({schema['description']})" if "description" in schema else ""
    if isinstance(value, str) and wanted in ("number", "integer") and _reads_as_float(value):
        hint = " (a number in quotes is text: drop the quotes)"
    return f"{shown} is not {words}{hint}"


def _reads_as_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _unit(schema: Mapping[str, Any]) -> str:
    """`` s`` from a description ending its first sentence with ``[s]``; "" without a unit."""
    description = str(schema.get("description", ""))
    if "[" not in description:
        return ""
    unit = description.split("[", 1)[1].split("]", 1)[0]
    return "" if unit in ("-", "") else f" {unit}"


def find_shipped(
    spec: str | Path, folder: Path, what: str, error: type[InputError], suffix: str = ".yaml"
) -> Path:
    """The file ``spec`` names: an existing path, else the name of a ``suffix`` file in ``folder``.

    A path that exists wins; otherwise a bare name (``pendulum3r``, or ``pendulum3r.yaml``)
    names a file shipped in ``folder``. Any other path is returned as it is, so that reading
    it reports what is wrong.

    Raises:
        InputError: (of class ``error``) ``spec`` is a bare name that is neither a file nor a
            shipped one; the message lists the shipped ones.
    """
    path = Path(spec)
    try:
        if path.exists() or len(path.parts) != 1 or path.suffix not in ("", suffix):
            return path
        shipped = folder / f"{path.stem}{suffix}"
        if shipped.is_file():
            return shipped
    except (OSError, ValueError):  # a name too long for a path, or with a NUL in it
        return path
    names = ", ".join(sorted(p.stem for p in folder.glob(f"*{suffix}"))) or "none"
    raise error(
        excerpt(str(spec)), "", f"no such file, and not the name of a shipped {what} ({names})"
    )
