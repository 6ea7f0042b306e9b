"""What ``vla-gr <command> --help`` lists: the config keys a command reads, each with its
default in the recipe and a one-line meaning.

The meaning of a key is the comment written with its field in the schema (``schema.py``,
``training_schema.py``, ...): the comment at the end of the field's line(s), else the comment
lines right above it. A section of the config is introduced by its class's docstring. A
command lists the sections of :data:`COMMAND_SECTIONS`; the model's components (``model.<part>``)
are too many to list key by key, so ``vla-gr train --help`` names each with its meaning and
``--cfg job --package model.<part>`` prints its keys and values.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import io
import re
import shutil
import textwrap
import tokenize
import typing

#: Bare ``key=value`` overrides of ``vla-gr eval`` that mean ``eval.key=value``.
EVAL_ALIASES = (
    "agent",
    "agents",
    "checkpoint",
    "split",
    "episodes",
    "num_episodes",
    "first_episode",
    "workers",
    "backend",
    "output_dir",
    "device",
)
#: command -> (section, bare keys short for ``<section>.<key>``).
SHORT_KEYS: dict[str, tuple[str, tuple[str, ...]]] = {"eval": ("eval", EVAL_ALIASES)}
#: The config sections each command reads, in the order its ``--help`` lists them.
COMMAND_SECTIONS: dict[str, tuple[str, ...]] = {
    "collect": ("collect", "expert", "env", "seed"),
    "demo": ("demo", "env", "seed"),
    "eval": ("eval", "env", "seed"),
    "train": ("training", "logging", "pipeline", "model", "seed"),
}
#: Sections whose nested sections are named, not listed key by key (except those given).
SUMMARISED: dict[str, tuple[str, ...]] = {"model": ("peft",)}
#: Comments that steer tools, not readers.
_DIRECTIVE = re.compile(r"#\s*(fmt:|noqa|type:|pragma)")
#: A comment block that titles a group of fields ("# Data.", "# Precision / speed.").
_TITLE = re.compile(r"^[A-Z][\w /]*\.$")


@functools.cache
def field_notes(cls: type) -> dict[str, str]:
    """``{field: one-line meaning}`` of dataclass ``cls`` from the comments of its source;
    a field without a comment is absent."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    comments: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT and not _DIRECTIVE.match(tok.string):
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
    lines = source.splitlines()
    notes: dict[str, str] = {}
    body = ast.parse(source).body[0].body
    for node in body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        own = [comments[n] for n in range(node.lineno, node.end_lineno + 1) if n in comments]
        if not own:  # the comment lines right above the field
            n = node.lineno - 1
            while n >= 1 and lines[n - 1].strip().startswith("#"):
                if n in comments:
                    own.insert(0, comments[n])
                n -= 1
            if len(own) == 1 and _TITLE.match(own[0]) and len(own[0].split()) <= 3:
                own = []
        if own:
            notes[node.target.id] = one_line(" ".join(own))
    return notes


def one_line(text: str) -> str:
    """The first sentence of ``text`` (a comment may go on after it)."""
    text = re.sub(r":\w+:`~?(?:[\w.]+\.)?(\w+)`", r"`\1`", text)  # :func:`~a.b` -> `b`
    text = " ".join(text.replace("``", "`").split())
    match = re.search(r"(?<=[\w)\]`'])(?<!e\.g)(?<!i\.e)\.(\s|$)", text)
    return text[: match.start()] if match else text


def section_note(cls: type) -> str:
    """The first sentence of dataclass ``cls``'s docstring ("" without one)."""
    doc = inspect.getdoc(cls) or ""
    if doc.startswith(f"{cls.__name__}("):  # the signature dataclasses write
        return ""
    return one_line(doc.split("\n\n")[0])


def _nested_types(cls: type) -> dict[str, type]:
    """``{field: dataclass type}`` of the fields of ``cls`` that are sections themselves."""
    hints = typing.get_type_hints(cls)
    return {
        f.name: hints[f.name]
        for f in dataclasses.fields(cls)
        if isinstance(hints.get(f.name), type) and dataclasses.is_dataclass(hints[f.name])
    }


def format_value(value) -> str:
    """A default as a ``key=value`` override writes it: null, true, [a,b], a string as is."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        text = "[" + ",".join(format_value(v) for v in value) + "]"
        if value and isinstance(value[0], dict):
            text = f"[{len(value)} items]"
        elif len(text) > 48:
            text = f"[{format_value(value[0])},... {len(value)} items]"
        return text
    if isinstance(value, dict):
        return "{" + ",".join(value) + "}" if len(value) <= 4 else f"{{... {len(value)} keys}}"
    if isinstance(value, str) and value == "":
        return "''"
    return str(value)


def key_rows(cfg: dict, root: type, section: str) -> list[tuple[str, str, str]]:
    """``(key, default, meaning)`` rows of ``section`` (a dotted path, or a root key such as
    ``seed``) of the resolved config ``cfg`` (plain containers) whose schema is ``root``; a
    nested section listed in :data:`SUMMARISED` as a ``<key>.*`` row with its meaning."""
    parts = section.split(".")
    parent, value = root, cfg
    for part in parts[:-1]:
        parent, value = _nested_types(parent)[part], value[part]
    name = parts[-1]
    nested = _nested_types(parent)
    if name not in nested:  # a key of the root
        return [(section, format_value(value[name]), field_notes(parent).get(name, ""))]
    cls, value = nested[name], value[name]
    rows: list[tuple[str, str, str]] = []
    notes, children = field_notes(cls), _nested_types(cls)
    expanded = SUMMARISED.get(section)
    for f in dataclasses.fields(cls):
        key = f"{section}.{f.name}"
        if f.name in children and expanded is not None and f.name not in expanded:
            count = len(dataclasses.fields(children[f.name]))
            meaning = section_note(children[f.name]) or notes.get(f.name, "")
            rows.append((f"{key}.*", f"({count} keys)", meaning))
        elif f.name in children:
            rows += key_rows(cfg, root, key)
        else:
            rows.append((key, format_value(value[f.name]), notes.get(f.name, "")))
    return rows


def command_rows(command: str, cfg: dict, root: type) -> list[tuple[str, str, str]]:
    """The rows ``vla-gr <command> --help`` lists, bare keys written bare."""
    section, short = SHORT_KEYS.get(command, ("", ()))
    rows = []
    for name in COMMAND_SECTIONS[command]:
        for key, default, meaning in key_rows(cfg, root, name):
            head, _, tail = key.rpartition(".")
            rows.append((tail if head == section and tail in short else key, default, meaning))
    return rows


def format_rows(
    rows: list[tuple[str, str, str]], width: int = 44, columns: int | None = None
) -> list[str]:
    """Aligned ``  key=default  meaning`` lines, the meaning wrapped to ``columns`` (default:
    the terminal's width) in its own column."""
    columns = columns or shutil.get_terminal_size().columns
    out = []
    for key, default, meaning in rows:
        left = f"{key}={default}" if not key.endswith(".*") else f"{key} {default}"
        text = textwrap.wrap(meaning, max(columns - width, 30)) or [""]
        if len(left) >= width - 2:
            out.append(f"  {left}")
        else:
            out.append(f"  {left:{width - 2}}{text.pop(0)}".rstrip())
        out += [f"{'':{width}}{line}" for line in text if line]
    return out


def keys_help(command: str, config_name: str) -> str:
    """The text ``vla-gr <command> --help`` ends with: the command's keys, their defaults in
    recipe ``config_name`` and their meanings (or one line saying why the recipe does not
    compose)."""
    from omegaconf import OmegaConf

    from vla_gr.configs import load_config
    from vla_gr.configs.schema import VLAGRConfig
    from vla_gr.errors import UserError

    try:
        resolved, _ = load_config(config_name, ())
    except UserError as err:
        return f"keys: not listed ({err})"
    cfg = OmegaConf.to_container(resolved, resolve=True)
    section, short = SHORT_KEYS.get(command, ("", ()))
    lines = [
        f"keys (key=value; defaults of --config-name {config_name}; --cfg job prints the "
        "resolved config):"
    ]
    if short:
        note = f"({', '.join(short)} are short for {section}.<key>)"
        columns = shutil.get_terminal_size().columns
        lines += ["  " + line for line in textwrap.wrap(note, columns - 2)]
    rows = command_rows(command, cfg, VLAGRConfig)
    lines += format_rows(rows)
    parts = [key for key, _, _ in rows if key.endswith(".*")]
    if parts:
        lines.append(
            f"  (the keys of {parts[0]} and the other parts: vla-gr {command} --cfg job "
            f"--package {parts[0][:-2]})"
        )
    return "\n".join(lines)
