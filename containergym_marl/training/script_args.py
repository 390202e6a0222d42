"""Command-line parsing for the baseline scripts' documented ``Args`` dataclasses (CleanRL style)."""

from __future__ import annotations

import argparse
import dataclasses
import typing


def parse_args(args_type, argv: list[str] | None = None):
    """Build an ``argparse`` parser from a dataclass: one ``--field-name`` option per field, the
    field's default (or default factory) as default, ``metadata["choices"]`` as choices, the class
    docstring as description. A ``list[str]`` field takes any number of values (``--hp a=1 b=2``)."""
    parser = argparse.ArgumentParser(description=args_type.__doc__,
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    hints = typing.get_type_hints(args_type)
    for f in dataclasses.fields(args_type):
        flag = "--" + f.name.replace("_", "-")
        kind = hints[f.name]
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if kind is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default)
        elif typing.get_origin(kind) is list:
            parser.add_argument(flag, nargs="*", type=str, default=default, metavar="VALUE")
        else:
            base = next((t for t in typing.get_args(kind) if t is not type(None)), kind)
            parser.add_argument(flag, type=base if base in (int, float, str) else str, default=default,
                                choices=f.metadata.get("choices"))
    return args_type(**vars(parser.parse_args(argv)))
