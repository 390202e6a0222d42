"""MkDocs hooks (``mkdocs.yml``: ``hooks: [docs/hooks.py]``): parts of pages generated at build time
from the package and the repository, so that they cannot drift from the code.

A page asks for them with one HTML comment on a line of its own:

- ``<!-- cli: train -->``: ``containergym-marl train --help`` (``cli:`` alone: the top-level help),
  from the parser the command itself uses (:func:`containergym_marl.cli.build_parser`);
- ``<!-- docstring: dotted.name -->``: an object's docstring as Markdown (an environment's card);
  ``<!-- docstring-text: dotted.name -->``: the same as preformatted text;
- ``<!-- include: PATH -->``: a Markdown file of the repository (``CHANGELOG.md``), headings one level down
  with ``<!-- include: PATH shift=1 -->``;
- ``<!-- configs -->``: the table of the built-in plant configurations.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import io
import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DIRECTIVE = re.compile(r"^<!-- (?P<kind>cli|docstring|docstring-text|include|configs)(?::\s*(?P<arg>[^>]*?))?\s*-->$",
                       re.M)
_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc):`(?P<tilde>~?)(?P<name>[^`]+)`")


def cli_help(command: str = "") -> str:
    """The ``--help`` text of ``containergym-marl [command]`` at a fixed width of 100 columns."""
    from containergym_marl.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        parser = build_parser()
        if command:
            sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
            parser = sub.choices[command]
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            parser.print_help()
        return out.getvalue()
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def _object(dotted: str):
    module, _, name = dotted.rpartition(".")
    try:
        return importlib.import_module(dotted)
    except ImportError:
        return getattr(importlib.import_module(module), name)


def docstring_markdown(dotted: str) -> str:
    """A docstring with Sphinx roles as code and its ``##`` sections one level down (``###``)."""
    doc = inspect.getdoc(_object(dotted)) or ""
    doc = _ROLE.sub(lambda m: f"``{m['name'].rsplit('.', 1)[-1] if m['tilde'] else m['name']}``", doc)
    return re.sub(r"^(#+) ", lambda m: "#" + m[1] + " ", doc, flags=re.M)


def include(arg: str) -> str:
    path, _, option = arg.partition(" ")
    text = (ROOT / path).read_text(encoding="utf-8")
    shift = int(option.split("=", 1)[1]) if option.startswith("shift=") else 0
    if shift:
        text = re.sub(r"^(#+) ", lambda m: "#" * (len(m[1]) + shift) + " ", text, flags=re.M)
    return text


def configs_table() -> str:
    """Every built-in configuration: its size, time step, episode length and plant-level parameters."""
    from containergym_marl import list_configs, load_config

    lines = ["| name | n | m | δ (s) | T (steps) | v₀ ~ U[a, b] | v_max | r_min | r_pen |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name in list_configs():
        c = load_config(name)
        vmax = sorted({s.max_volume for s in c.containers})
        lines.append(f"| `{name}` | {c.n_containers} | {c.num_processing_units} | {c.timestep_s:g} | {c.episode_length_steps} | "
                     f"[{c.initial_volume_min:g}, {c.initial_volume_max:g}] | "
                     f"{', '.join(f'{v:g}' for v in vmax)} | {c.overflow_reward:g} | {c.penalty_reward:g} |")
    lines += ["", "Their descriptions (`load_config(name).description`):", ""]
    lines += [f"- `{name}`: {load_config(name).description}" for name in list_configs()]
    return "\n".join(lines) + "\n"


def expand(markdown: str) -> str:
    """``markdown`` with every directive replaced by what it asks for."""
    def replace(m: re.Match) -> str:
        kind, arg = m["kind"], (m["arg"] or "").strip()
        if kind == "cli":
            return "```text\n" + cli_help(arg).rstrip("\n") + "\n```"
        if kind == "docstring":
            return docstring_markdown(arg)
        if kind == "docstring-text":
            return "```text\n" + (inspect.getdoc(_object(arg)) or "") + "\n```"
        if kind == "include":
            return include(arg)
        return configs_table()

    return DIRECTIVE.sub(replace, markdown)


def on_page_markdown(markdown, page, config, files, **kwargs):  # MkDocs event
    return expand(markdown)
