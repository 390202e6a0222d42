"""Progress in a Jupyter notebook: a notebook run by a real kernel (nbclient, as Jupyter runs it)
draws the progress rows of a bar and of ``train`` in an output widget under the cell; the same code
in a plain process (stderr not a terminal) writes nothing."""

from __future__ import annotations

import re

import nbformat
from nbclient import NotebookClient

ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _run(cells: list[str], cwd) -> nbformat.NotebookNode:
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(c) for c in cells]
    # the kernel is this interpreter's (ipykernel's native spec); widget outputs are kept in the state
    NotebookClient(nb, timeout=300, kernel_name="python3", store_widget_state=True,
                   resources={"metadata": {"path": str(cwd)}}).execute()
    return nb


def _widget_texts(nb: nbformat.NotebookNode) -> list[str]:
    """The plain text of every output captured by the notebook's Output widgets (rich's live display)."""
    state = nb.metadata["widgets"]["application/vnd.jupyter.widget-state+json"]["state"]
    return [ANSI.sub("", out["data"]["text/plain"]) for w in state.values() if w["model_name"] == "OutputModel"
            for out in w["state"].get("outputs", []) if "text/plain" in out.get("data", {})]


def _widget_views(cell: nbformat.NotebookNode) -> list[str]:
    return [o["data"]["application/vnd.jupyter.widget-view+json"]["model_id"] for o in cell.outputs
            if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]


def test_a_notebook_shows_progress_rows_for_a_bar_and_for_train(tmp_path):
    nb = _run([
        "import time\n"
        "from containergym_marl.progress_bar import Bar\n"
        "with Bar('counting', 40, 'steps') as bar:\n"
        "    for i in range(41):\n"
        "        bar.advance_to(i)\n"
        "        time.sleep(0.02)\n",
        "from containergym_marl.training import TrainArgs, train\n"
        "train(TrainArgs(algo='fast_shared_ppo', config='n5_m2_dt120', timesteps=6000, n_envs=2, out='run',\n"
        "                hyperparams={'n_steps': 16, 'minibatch_size': 64}))\n",
    ], tmp_path)
    bar_cell, train_cell = nb.cells
    assert len(_widget_views(bar_cell)) == 1 and len(_widget_views(train_cell)) == 1  # one widget per display
    texts = _widget_texts(nb)
    counting = [t for t in texts if t.startswith("counting")]
    assert counting and all(re.search(r"\d+%\s+\d+/40 steps", t) for t in counting)
    training = [t for t in texts if "samples" in t]
    assert training and all("/6000 samples" in t.replace(",", "") or "/6.0k samples" in t for t in training)
    assert (tmp_path / "run" / "run.json").is_file()
    # nothing of it went to the cells' plain streams (no carriage returns or escape codes in the notebook)
    streams = "".join(o.get("text", "") for c in nb.cells for o in c.outputs if o["output_type"] == "stream")
    assert "\r" not in streams and "\x1b[" not in streams


def test_outside_a_notebook_and_a_terminal_nothing_is_drawn(tmp_path, capfd):
    from containergym_marl.progress_bar import Bar, in_notebook

    assert not in_notebook()
    with Bar("counting", 3, "steps") as bar:
        for i in range(4):
            bar.advance_to(i)
    assert not bar.live and not bar.notebook
    captured = capfd.readouterr()
    assert captured.err == "" and captured.out == ""


def test_a_notebook_without_ipywidgets_gets_a_warning_naming_the_extra(monkeypatch):
    import sys

    import pytest

    from containergym_marl import progress_bar

    monkeypatch.setattr(progress_bar, "in_notebook", lambda: True)
    monkeypatch.setitem(sys.modules, "ipywidgets", None)  # import ipywidgets raises ImportError
    with pytest.warns(UserWarning, match=r"containergym-marl\[notebook\]"):
        bar = progress_bar.Bar("counting", 3, "steps")
    bar.close()
    assert not bar.live and not bar.notebook
