"""Options written once: each field of an entry point's arguments dataclass carries its own
command-line help, and the argparse parser is generated from the dataclass (CleanRL's ``Args``
pattern, without a dependency).

    @dataclass
    class TrainArgs:
        seed: int = option(1, help="training seed")

    add_options(parser, TrainArgs)          # --seed, with its help and default
    args = from_namespace(TrainArgs, parser.parse_args())

The arguments a command line does not give are absent from the parsed namespace
(``argparse.SUPPRESS``), so :func:`from_namespace` keeps the dataclass's defaults and a caller can
tell what was given (:func:`given`).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import MISSING, Field, field, fields
from typing import Any, Callable


def option(default: Any = MISSING, *, help: str | Callable[[], str], default_factory: Any = MISSING, flag: str | None = None,
           type: Callable[[str], Any] | None = None, choices: Any = None, nargs: str | None = None,
           metavar: str | None = None, group: str | None = None, action: str | None = None,
           convert: Callable[[Any, str], Any] | None = None, show_default: bool = True) -> Any:
    """A dataclass field that is also a command-line option.

    ``flag``: the option's name (default ``--field-name``); ``choices`` and ``help``: a value, or
    a callable returning it when the parser is built (from a registry); ``convert(value, flag)``: turns the parsed
    value into the field's (e.g. ``KEY=VALUE`` items into a dict), raising ValueError naming
    ``flag``; ``group``: the help section; ``action``: argparse's (``store_true``, ``store_false``).
    """
    meta = {"help": help, "flag": flag, "type": type, "choices": choices, "nargs": nargs, "metavar": metavar,
            "group": group, "action": action, "convert": convert, "show_default": show_default}
    return field(default=default, default_factory=default_factory, metadata={"option": meta})


def option_fields(cls) -> list[Field]:
    """The fields of ``cls`` that are command-line options, in definition order."""
    return [f for f in fields(cls) if "option" in f.metadata]


def flag_of(f: Field) -> str:
    return f.metadata["option"]["flag"] or "--" + f.name.replace("_", "-")


def _default(f: Field) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return MISSING


def _shown(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return " ".join(map(str, value)) if value else "none"
    if isinstance(value, dict):
        return " ".join(f"{k}={v}" for k, v in value.items()) if value else "none"
    return str(value)


def add_options(parser: argparse.ArgumentParser, cls, *, groups: dict[str, Any] | None = None,
                exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    """One argument per option field of ``cls`` (:func:`option`), except ``exclude``; returns the
    help sections by name. ``groups`` maps a section's name to its description, or to a section the
    caller made (to put its own arguments first); a field without a group goes to the parser itself.
    A field without a default is a required option. Each help ends with the default unless it names
    its own."""
    sections = {name: g for name, g in (groups or {}).items() if isinstance(g, argparse._ArgumentGroup)}
    for f in option_fields(cls):
        if f.name in exclude:
            continue
        meta = f.metadata["option"]
        where = parser
        if meta["group"] is not None:
            if meta["group"] not in sections:
                sections[meta["group"]] = parser.add_argument_group(meta["group"], (groups or {}).get(meta["group"]))
            where = sections[meta["group"]]
        default = _default(f)
        text = meta["help"]() if callable(meta["help"]) else meta["help"]
        if meta["show_default"] and "default" not in text and default is not MISSING and meta["action"] is None:
            text += f" (default: {_shown(default)})"
        flag = flag_of(f)
        kwargs: dict[str, Any] = {"help": text, "default": argparse.SUPPRESS}
        if flag.startswith("-"):
            kwargs["dest"] = f.name
        if meta["action"] is not None:
            kwargs["action"] = meta["action"]
        else:
            choices = meta["choices"]() if callable(meta["choices"]) else meta["choices"]
            kwargs.update({k: v for k, v in (("type", meta["type"]), ("nargs", meta["nargs"]),
                                             ("metavar", meta["metavar"])) if v is not None})
            if choices is not None:
                kwargs["choices"] = list(choices)
            if default is MISSING and flag.startswith("-"):
                kwargs["required"] = True
        where.add_argument(flag, **kwargs)
    return sections


def given(cls, ns: argparse.Namespace) -> list[str]:
    """The option fields of ``cls`` that the parsed command line ``ns`` gives."""
    return [f.name for f in option_fields(cls) if hasattr(ns, f.name)]


def values(cls, ns: argparse.Namespace) -> dict[str, Any]:
    """The given options' values, converted to the fields' types (ValueError naming the flag)."""
    out = {}
    for f in option_fields(cls):
        if hasattr(ns, f.name):
            convert = f.metadata["option"]["convert"]
            value = getattr(ns, f.name)
            out[f.name] = convert(value, flag_of(f)) if convert is not None else value
    return out


def from_namespace(cls, ns: argparse.Namespace, **overrides: Any):
    """``cls`` built from the parsed command line: given options converted, the others at their
    dataclass defaults, ``overrides`` last."""
    return cls(**{**values(cls, ns), **overrides})


def parse(cls, argv: list[str] | None = None, description: str | None = None):
    """``cls`` from a command line: a parser generated from its option fields (a script's ``Args``,
    CleanRL style); a value a field's ``convert`` refuses is a usage error naming the option."""
    parser = argparse.ArgumentParser(description=description or cls.__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_options(parser, cls)
    try:
        return from_namespace(cls, parser.parse_args(argv))
    except ValueError as exc:
        parser.error(str(exc))


def key_values(items: list[str] | None, flag: str) -> dict[str, Any]:
    """``KEY=VALUE`` items as a dict; each value read as JSON where it parses (numbers, booleans,
    lists), else kept as text. A ValueError names ``flag`` and the item."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{flag}: expected KEY=VALUE, got {item!r}")
        if key in out:
            raise ValueError(f"{flag}: {key} given more than once")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (budgets, simulations, episodes)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


__all__ = ["add_options", "flag_of", "from_namespace", "given", "key_values", "option", "option_fields", "parse",
           "positive_int", "values"]
