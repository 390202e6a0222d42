"""AgileRL on ``container_agents_v1``: the integrations page's recipe (docs/integrations.md, block
``# AgileRL: …``) runs as written, trains one IPPO actor and critic shared by all container agents
(AgileRL's group ``container``), and the masks reach that actor as masks: while training it never
requests emptying where the mask forbids it, and the trained actor requests there only when it is
not given the masks. The last tests check that the AgileRL bugs the page names are still there,
so that the workaround goes when AgileRL fixes them.

Needs AgileRL, which cannot share the ``clients`` extra's environment (AgileRL 2.58 pins
tensordict 0.13 and PettingZoo < 1.27): ``./run test-agilerl`` builds ``.venv-agilerl`` with the
``agilerl`` extra; elsewhere these tests are skipped.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("agilerl", reason="AgileRL is not installed: pip install 'containergym-marl[agilerl]' "
                                      "(./run test-agilerl builds .venv-agilerl with it)")
import torch  # noqa: E402
from agilerl.algorithms import IPPO  # noqa: E402

from containergym_marl import container_agents_v1  # noqa: E402
from tests.clients.test_readme import one_torch_thread, run_snippet  # noqa: E402, F401 (a fixture)

AGENTS = [f"container_{i}" for i in range(5)]


@pytest.fixture(scope="module")
def recipe(tmp_path_factory):
    """The block's variables, and what IPPO saw while the block trained: every ``get_action``
    call's masks and actions, every ``learn`` call's losses and the masks its actor was called
    with. Module-scoped: the block trains once (~10 s) for all the tests below."""
    seen = {"acted": [], "losses": [], "learn_masks": []}
    get_action, learn = IPPO.get_action, IPPO.learn

    def recording_get_action(self, obs, infos=None, *args, **kwargs):
        out = get_action(self, obs, infos, *args, **kwargs)
        seen["acted"].append(({a: (infos or {}).get(a, {}).get("action_mask") for a in obs}, out[0]))
        return out

    def recording_learn(self, experiences):
        actor = self.actors["container"]
        forward = actor.forward  # AgileRL's modules call forward directly: torch's hooks never run

        def recording_forward(obs, action_mask=None, *args, **kwargs):
            seen["learn_masks"].append(action_mask)
            return forward(obs, action_mask, *args, **kwargs)

        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(actor, "forward", recording_forward, raising=False)
            losses = learn(self, experiences)
        seen["losses"].append(losses)
        return losses

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(IPPO, "get_action", recording_get_action)
        patch.setattr(IPPO, "learn", recording_learn)
        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # see test_readme.one_torch_thread
        torch.manual_seed(0)
        try:
            namespace = run_snippet("AgileRL", patch, tmp_path_factory.mktemp("agilerl"))
        finally:
            torch.set_num_threads(threads)
    return {**namespace, "seen": seen}


def test_recipe_trains_one_shared_policy(recipe):
    ippo, env, seen = recipe["ippo"], recipe["env"], recipe["seen"]
    assert env.possible_agents == AGENTS  # v1's default names, which AgileRL groups by the text before "_"
    assert list(ippo.actors) == list(ippo.critics) == ["container"]  # one actor and one critic for all 5
    assert ippo.steps == 1_024 and recipe["population"] == [ippo]
    # 1,024 steps in rollouts of learn_step=256: four updates, each one of the group's actor and critic
    assert len(seen["losses"]) == 4 and all(set(losses) == {"container"} for losses in seen["losses"])
    assert all(np.isfinite(losses["container"]) for losses in seen["losses"])
    assert len(recipe["fitnesses"]) == 1 and np.isfinite(recipe["fitnesses"][0])


def test_masks_reach_the_policy_while_training(recipe):
    """Every action IPPO took during the block (training and its evaluation) came with the 5
    agents' masks, as lists, and none requests where its mask forbids it."""
    acted = recipe["seen"]["acted"]
    assert len(acted) >= 1_024
    masked = 0
    for masks, actions in acted:
        assert set(masks) == set(AGENTS) and all(isinstance(m, list) and len(m) == 2 for m in masks.values())
        for agent, mask in masks.items():
            action = int(np.asarray(actions[agent]).item())
            masked += mask[1] == 0
            assert mask[action] == 1, (agent, mask, action)
    assert masked > 50  # n5_m2_dt120 with a near-random policy: both PUs are often busy


def count_requests(ippo, mask_lists, with_masks: bool, steps: int = 300, seed: int = 0) -> tuple[int, int, int]:
    """The trained actor on a plant whose PUs are often all busy (δ = 60 s), given the masks or
    not: (agent steps while masked, requests while masked, requests while allowed)."""
    env = container_agents_v1.parallel_env("n5_m2_dt60", action_masking=True)
    torch.manual_seed(seed)
    obs, infos = env.reset(seed=seed)
    masked = requests_masked = requests_allowed = 0
    for _ in range(steps):
        given = mask_lists(infos) if with_masks else {a: {} for a in infos}  # no "action_mask": no mask
        actions = {a: int(np.asarray(v).item()) for a, v in ippo.get_action(obs, given)[0].items()}
        for agent, action in actions.items():
            allowed = bool(infos[agent]["action_mask"][1])
            masked += not allowed
            requests_masked += action == 1 and not allowed
            requests_allowed += action == 1 and allowed
        obs, _, _, _, infos = env.step(actions)
        if not env.agents:
            obs, infos = env.reset()
    return masked, requests_masked, requests_allowed


def test_the_trained_policy_obeys_the_masks(recipe, one_torch_thread):  # noqa: F811 (the fixture imported above)
    """0 requests while masked with the masks; without them, the same actor (same seeds) requests
    while masked: the masks, not the observations, stop the requests."""
    ippo, lists = recipe["ippo"], recipe["MaskLists"].lists
    ippo.set_training_mode(False)
    masked, requests_masked, requests_allowed = count_requests(ippo, lists, with_masks=True)
    assert masked > 100 and requests_masked == 0 and requests_allowed > 0
    masked, requests_masked, _ = count_requests(ippo, lists, with_masks=False)
    assert masked > 100 and requests_masked > 0


def test_agilerl_bugs_worked_around_are_still_there(recipe):
    ippo = recipe["ippo"]
    env = container_agents_v1.parallel_env("n5_m2_dt120", action_masking=True)
    obs, infos = env.reset(seed=0)
    # 1. numpy masks (PettingZoo's usual form) fail in IPPO.extract_action_masks: `None in group_masks`
    #    compares each mask array with None
    with pytest.raises(ValueError, match="truth value of an array"):
        ippo.get_action(obs, infos)
    # 2. a list of numpy integers is not refused but dropped: coerce_action_mask takes it for no mask
    numpy_items = {a: {**info, "action_mask": list(info["action_mask"])} for a, info in infos.items()}
    assert ippo.extract_action_masks(numpy_items) == {"container": None}
    masks = ippo.extract_action_masks(recipe["MaskLists"].lists(infos))["container"]  # the recipe's lists
    assert masks.shape == (5, 2)
    # 3. IPPO.learn recomputes the log-probabilities without the masks: the recipe's four updates
    #    called the actor, never with a mask
    learn_masks = recipe["seen"]["learn_masks"]
    assert learn_masks and all(mask is None for mask in learn_masks)


def test_agilerl_imports_peft():
    """AgileRL 2.58 needs peft to import its algorithms but declares it only in its LLM extras;
    the agilerl extra installs it (pyproject.toml)."""
    code = textwrap.dedent("""
        import sys
        sys.modules["peft"] = None  # makes `import peft` fail
        try:
            import agilerl.algorithms
        except ImportError as e:
            print("ImportError:", e)
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert proc.returncode == 0, proc.stderr
    assert "ImportError" in proc.stdout and "peft" in proc.stdout
