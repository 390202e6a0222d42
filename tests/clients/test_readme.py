"""The code of the documentation's integrations page (docs/integrations.md) runs as written.

Each ```python block of that page starts with a comment naming its library (``# TorchRL: …``).
Every test here takes one block from the page unchanged, executes it (in a temporary working
directory: BenchMARL writes its logs there) and checks what the block built, so a page that
drifts from the libraries' or the package's API fails here.

The skrl block is run and checked by tests/clients/test_skrl.py, the AgileRL block by
tests/clients/test_agilerl.py (``./run test-agilerl``, AgileRL's own environment), both with
:func:`run_snippet`.

TorchRL, BenchMARL, Tianshou, RLlib and skrl come from the ``clients`` extra (``./run test-clients``,
which runs the ``slow`` ones too); SB3, sb3-contrib and SuperSuit from the ``train`` extra, so the
SB3 block runs in ``./run test`` (default environment) and is skipped in the clients environment.
Each test is skipped where its library is missing.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

PAGE = Path(__file__).resolve().parents[2] / "docs" / "integrations.md"
LIBRARIES = ("TorchRL", "BenchMARL", "RLlib", "Tianshou", "skrl", "AgileRL", "SB3")
#: blocks longer than 20 lines: skrl has no built-in masked policy, so its block defines two models;
#: AgileRL's carries a wrapper that hands the masks over as lists (an AgileRL bug)
MAX_LINES = {"skrl": 40, "AgileRL": 25}


def readme_snippets() -> dict[str, str]:
    """The page's python blocks, by the library named in their first line (``# Name: …``)."""
    text = PAGE.read_text(encoding="utf-8")
    snippets = {}
    for block in re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M):
        first = block.split("\n", 1)[0]
        match = re.match(r"# ([^\s:]+)", first)
        assert match, f"a python block of {PAGE.name} does not start with '# Library: ...': {first!r}"
        assert match[1] not in snippets, f"two blocks for {match[1]}"
        snippets[match[1]] = block
    return snippets


def run_snippet(name: str, monkeypatch, tmp_path) -> dict:
    """Executes the page's block of ``name`` in ``tmp_path``; returns its variables."""
    code = readme_snippets()[name]
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": f"readme_{name.lower()}"}
    exec(compile(code, f"docs/integrations.md[{name}]", "exec"), namespace)
    return namespace


@pytest.fixture
def one_torch_thread():
    """The blocks' small networks run fastest on one torch thread; more threads stall on a busy
    2-core machine (the SB3 block: ~4 s on one thread, ~75 s on two beside a training run)."""
    torch = pytest.importorskip("torch")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_section_has_one_block_per_library():
    snippets = readme_snippets()
    assert tuple(snippets) == LIBRARIES
    for name, code in snippets.items():
        compile(code, f"docs/integrations.md[{name}]", "exec")  # valid Python even where the library is missing
        assert len(code.splitlines()) <= MAX_LINES.get(name, 20), f"the {name} block is no longer short"


def test_torchrl(monkeypatch, tmp_path, one_torch_thread):
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    ns = run_snippet("TorchRL", monkeypatch, tmp_path)
    td, env, wrapped = ns["td"], ns["env"], ns["wrapped"]
    assert td.batch_size == (32, 100) and td["container", "observation"].shape == (32, 100, 5, 19)
    assert env.group_map == {"container": [f"container_{i}" for i in range(5)]}
    # the wrapper's options give what the comment says: one group, masks, the normalised state
    assert wrapped.group_map == env.group_map and wrapped.has_action_mask["container"]
    check_env_specs(wrapped, seed=0)
    rollout = wrapped.rollout(20)
    assert rollout["state"].shape == (20, 7)
    assert float(rollout["state"].max()) < 2  # normalised: not volumes up to 80 and timers up to ~830 s
    assert rollout["container", "action_mask"].shape == (20, 5, 2)


@pytest.mark.slow  # ~30-60 s: two MAPPO iterations with BenchMARL's default minibatches
def test_benchmarl(monkeypatch, tmp_path, one_torch_thread):
    pytest.importorskip("benchmarl")
    ns = run_snippet("BenchMARL", monkeypatch, tmp_path)
    experiment = ns["experiment"]
    assert experiment.n_iters_performed == 2 and experiment.total_frames == 12_000
    assert experiment.state_spec is not None and "state" in experiment.state_spec.keys()  # MAPPO's critic
    folders = list(tmp_path.glob("mappo_n5_m2_dt120_mlp__*"))
    assert len(folders) == 1 and any(folders[0].rglob("*.csv"))  # where the comment says


@pytest.mark.slow  # starts a local Ray instance
def test_rllib(monkeypatch, tmp_path, one_torch_thread):
    pytest.importorskip("ray.rllib")
    import ray

    ray.init(include_dashboard=False, log_to_driver=False)
    algo = None
    try:
        ns = run_snippet("RLlib", monkeypatch, tmp_path)
        algo, runners = ns["algo"], ns["result"]["env_runners"]
        assert runners["num_env_steps_sampled"] == 200
        # one module, "shared", acted for all 5 agents at every step
        assert dict(runners["num_module_steps_sampled"]) == {"shared": 5 * 200}
        assert set(runners["num_agent_steps_sampled"].values()) == {200}
    finally:
        if algo is not None:
            algo.stop()
        ray.shutdown()


def test_tianshou(monkeypatch, tmp_path, one_torch_thread):
    pytest.importorskip("tianshou")
    ns = run_snippet("Tianshou", monkeypatch, tmp_path)
    stats, buffer = ns["stats"], ns["collector"].buffer
    n = 5
    assert stats.n_collected_steps >= 2_000 and len(buffer) == stats.n_collected_steps
    if stats.n_collected_episodes:  # an untrained policy may or may not overflow within 2,000 steps
        # team rewards: in every finished episode, every agent's return is the same (the plant's)
        assert stats.returns.shape == (stats.n_collected_episodes, n)
        assert np.allclose(stats.returns, stats.returns[:, :1])
    # the policy got the masks: requests allowed exactly while a PU is free (observation entry 8)
    obs = buffer.sample(0)[0].obs  # everything collected
    assert np.asarray(obs.mask).shape == (len(buffer), 2)
    np.testing.assert_array_equal(np.asarray(obs.mask)[:, 1], np.asarray(obs.obs)[:, 8] > 0)


def test_sb3(monkeypatch, tmp_path, one_torch_thread):
    pytest.importorskip("sb3_contrib")
    pytest.importorskip("supersuit")
    ns = run_snippet("SB3", monkeypatch, tmp_path)
    native, stack, model = ns["native"], ns["stack"], ns["model"]
    assert native.num_envs == stack.num_envs == 8 * 5  # slots: simulations × agents
    assert model.num_timesteps == 2_560 and model.env.num_envs == 40
    assert native.action_masks().shape == (40, 2)
    stack.close()
