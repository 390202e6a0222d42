"""Progress displays, one style for training, evaluation and the sweep, through ``rich.progress``.

On a terminal a :class:`Display` draws one row per task: its description, a bar, the percentage,
done/total, the rate, the ETA and a status text; lines printed meanwhile (:meth:`Display.say`, or
``print``) appear above the rows. In a Jupyter notebook (a kernel: Jupyter, JupyterLab, VS Code,
Colab) the same rows are drawn in an output widget under the cell, redrawn in place, which needs
ipywidgets (the ``notebook`` extra; without it a warning names the extra and nothing is drawn). When
the stream is neither (a log file, a pipe, a captured test stream) nothing is drawn and nothing is
written: no carriage returns, no escape codes. A caller that wants something in a log (the sweep)
writes plain lines itself.

This module depends on rich and the standard library only (ipywidgets in a notebook).
"""

from __future__ import annotations

import sys
import warnings
from typing import Any, TextIO

from rich.console import Console
from rich.progress import BarColumn, Progress, ProgressColumn, Task, TaskID, TaskProgressColumn, TextColumn
from rich.table import Column
from rich.text import Text

from containergym_marl.extras import INSTALL


def format_duration(seconds: float | None) -> str:
    """``42s``, ``5m03s``, ``2h07m``; ``?`` when unknown."""
    if seconds is None or seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


def is_terminal(stream: Any) -> bool:
    """Whether ``stream`` is a terminal: its own ``isatty()``, not rich's guess, so that FORCE_COLOR
    (set by many CI services for colours) never turns a log into a stream of redrawn bars."""
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # a closed stream
        return False


def in_notebook() -> bool:
    """Whether this process is a Jupyter kernel running a notebook (Jupyter, JupyterLab, VS Code,
    Colab), where rich draws its rows in an output widget. IPython in a terminal is not one."""
    ipython_module = sys.modules.get("IPython")  # never imported here: a kernel has it loaded
    shell = ipython_module.get_ipython() if ipython_module is not None else None
    return shell is not None and (type(shell).__name__ == "ZMQInteractiveShell" or "google.colab" in str(type(shell)))


def _notebook_widgets() -> bool:
    """Whether ipywidgets (rich's notebook display) can be imported; a warning naming the extra if not."""
    try:
        import ipywidgets  # noqa: F401
    except ImportError:
        warnings.warn("progress rows in a notebook need ipywidgets, which is not installed; install the notebook "
                      f"extra: {INSTALL['notebook']}", stacklevel=3)
        return False
    return True


def _count(n: float) -> str:
    n = int(n)
    if n < 10_000:
        return f"{n:,}"
    return f"{n / 1e3:.1f}k" if n < 1_000_000 else f"{n / 1e6:.2f}M"


def _rate(task: Task) -> float | None:
    """A task's own measured rate (field ``rate``, None for none) where it reports one, else rich's
    estimate from the updates of the last 30 s."""
    return task.fields["rate"] if "rate" in task.fields else task.speed


def _cell() -> Column:
    """A column that never wraps (a row stays one line); the status text is cut first."""
    return Column(no_wrap=True)


class _CountColumn(ProgressColumn):
    """``0.90M/2.00M samples``."""

    def render(self, task: Task) -> Text:
        return Text(f"{_count(task.completed)}/{_count(task.total or 0)} {task.fields['unit']}")


class _RateColumn(ProgressColumn):
    """``2,345 samples/s``; two decimals below 10 (evaluation episodes take seconds)."""

    def render(self, task: Task) -> Text:
        rate = _rate(task)
        if not rate:
            return Text("")
        return Text(f"{rate:,.0f} {task.fields['unit']}/s" if rate >= 10 else f"{rate:.2f} {task.fields['unit']}/s")


class _EtaColumn(ProgressColumn):
    """``ETA 7m49s`` (field ``eta_s`` where the task computes its own, else what is left over the
    rate), ``in 12m03s`` once finished: the durations of the sweep's plain lines."""

    max_refresh = 0.5  # as rich's own TimeRemainingColumn: no jitter

    def render(self, task: Task) -> Text:
        if task.finished:
            return Text(f"in {format_duration(task.finished_time)}")
        if "eta_s" in task.fields:
            eta = task.fields["eta_s"]
        else:
            rate = _rate(task)
            eta = task.remaining / rate if rate and task.remaining is not None else None
        return Text(f"ETA {format_duration(eta)}")


class Display:
    """Rows of tasks on ``stream`` (default stderr: stdout stays for results) while it is a terminal
    and ``show`` holds, or in an output widget in a notebook (:attr:`notebook`); otherwise :attr:`live`
    is False and nothing is written. Use as a context manager (or call :meth:`close`), so that the
    terminal's cursor comes back even after an exception."""

    def __init__(self, stream: TextIO | None = None, show: bool = True):
        stream = stream or sys.stderr
        terminal = is_terminal(stream)
        self.notebook = show and not terminal and in_notebook() and _notebook_widgets()
        self.live = show and (terminal or self.notebook)
        self.console = Console(file=stream, force_terminal=self.live and not self.notebook,
                               force_jupyter=self.notebook, highlight=False)
        self.progress = Progress(
            TextColumn("{task.description}", markup=False, table_column=_cell()), BarColumn(bar_width=20),
            TaskProgressColumn(), _CountColumn(_cell()), _RateColumn(_cell()), _EtaColumn(_cell()),
            # the status takes what is left of the width (expand=True) and is cut with an ellipsis
            TextColumn("{task.fields[status]}", markup=False,
                       table_column=Column(no_wrap=True, overflow="ellipsis", ratio=1)),
            console=self.console, disable=not self.live, expand=True,
            # print() and warnings meanwhile go above the rows, but only from a standard stream that is
            # a terminal itself: a piped stdout keeps its content
            redirect_stdout=is_terminal(sys.stdout), redirect_stderr=is_terminal(sys.stderr))
        self.progress.start()

    def add(self, description: str, total: int, unit: str, completed: int = 0, status: str = "",
            **fields: Any) -> TaskID:
        """A new row; ``fields``: ``rate`` and ``eta_s`` for a task that measures its own."""
        return self.progress.add_task(description, total=total, completed=min(completed, total), unit=unit,
                                      status=status, **fields)

    def update(self, task: TaskID, completed: int | None = None, status: str | None = None, **fields: Any) -> None:
        if not self.live:  # called on every training step: skip rich's bookkeeping when nothing is drawn
            return
        if status is not None:
            fields["status"] = status
        self.progress.update(task, completed=completed, **fields)

    def remove(self, task: TaskID) -> None:
        self.progress.remove_task(task)

    def say(self, text: str) -> None:
        """A line above the rows."""
        if self.live:
            self.console.print(text, markup=False, soft_wrap=True)

    def close(self) -> None:
        self.progress.stop()

    def __enter__(self) -> Display:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Bar(Display):
    """A display of a single task (a training run's samples, an evaluation's episodes)."""

    def __init__(self, description: str, total: int, unit: str, completed: int = 0, stream: TextIO | None = None,
                 show: bool = True):
        super().__init__(stream, show)
        self.total = total
        self.task = self.add(description, total, unit, completed)

    def advance_to(self, completed: int, status: str | None = None) -> None:
        """``completed`` so far (capped at the total: SB3 may overshoot by a rollout)."""
        self.update(self.task, min(completed, self.total), status)
