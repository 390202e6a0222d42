"""skrl on ``container_agents_v1``: the integrations page's recipe (docs/integrations.md, block
``# skrl: …``) runs as written, trains one policy shared by all container agents, and that policy
reads the action masks as masks (it never requests emptying while no PU is free); the same policy
trains under skrl's MAPPO with a critic on the global state. The last test
checks that the three skrl bugs the recipe works around are still there, so that the workarounds
go when skrl fixes them.

Needs skrl (skipped without it; the ``clients`` extra installs it).
"""

from __future__ import annotations

import atexit
import dataclasses

import pytest

pytest.importorskip("skrl")
import torch  # noqa: E402
from skrl.envs.wrappers.torch import wrap_env  # noqa: E402
from skrl.memories.torch import RandomMemory  # noqa: E402
from skrl.models.torch import DeterministicMixin, Model  # noqa: E402
from skrl.multi_agents.torch.ippo import IPPO, IPPO_CFG  # noqa: E402
from skrl.multi_agents.torch.mappo import MAPPO, MAPPO_CFG  # noqa: E402
from skrl.trainers.torch import SequentialTrainer  # noqa: E402
from skrl.utils.spaces.torch import unflatten_tensorized_space  # noqa: E402

from containergym_marl import container_agents_v1  # noqa: E402
from tests.clients.test_readme import one_torch_thread, run_snippet  # noqa: E402, F401 (a fixture)


@pytest.fixture
def recipe(monkeypatch, tmp_path, one_torch_thread):  # noqa: F811 (the fixture imported above)
    """The block's variables. skrl's trainer registers an exit handler that closes the env and
    logs; it runs here instead, while pytest still captures the output (at exit it would log to
    a closed stream)."""
    at_exit = []
    monkeypatch.setattr(atexit, "register", lambda f: at_exit.append(f) or f)
    yield run_snippet("skrl", monkeypatch, tmp_path)
    for f in at_exit:
        f()


def test_recipe_trains_one_shared_policy(recipe):
    ippo, env = recipe["ippo"], recipe["env"]
    agents = [f"container_{i}" for i in range(5)]
    assert env.possible_agents == agents  # v1's default names
    policy, value = recipe["shared"]["policy"], recipe["shared"]["value"]
    assert all(ippo.policies[a] is policy and ippo.values[a] is value for a in agents)
    # 256 steps of rollouts of 64: every agent's memory filled with the last rollout, in the shared policy's inputs
    for a in agents:
        observations = ippo.memories[a].get_tensor_by_name("observations")
        assert observations.shape[0] == 64 and observations.shape[-1] == policy.num_observations == 2 + 19


def test_the_policy_obeys_the_masks(recipe):
    """The trained policy on a plant whose PUs are often all busy (δ = 60 s): never a request
    while masked, requests while allowed."""
    policy, space = recipe["shared"]["policy"], recipe["obs_space"]
    env = wrap_env(container_agents_v1.parallel_env("n5_m2_dt60", observation_mode="dict"))
    observations, _ = env.reset()
    masked = requests_masked = requests_allowed = 0
    for _ in range(300):
        with torch.no_grad():
            actions = {a: policy.act({"observations": observations[a]}, role="policy")[0] for a in env.agents}
        for a, action in actions.items():
            allowed = bool(unflatten_tensorized_space(space, observations[a])["action_mask"][0, 1])
            masked += not allowed
            requests_masked += int(action) == 1 and not allowed
            requests_allowed += int(action) == 1 and allowed
        observations, *_ = env.step(actions)
        if not env.agents:
            observations, _ = env.reset()
    assert masked > 100 and requests_masked == 0 and requests_allowed > 0


class StateValue(DeterministicMixin, Model):
    """MAPPO's centralised critic: the value of the global state (``state_mode="normalised"``)."""

    def __init__(self, state_space, action_space):
        Model.__init__(self, state_space=state_space, action_space=action_space)
        DeterministicMixin.__init__(self)
        self.net = torch.nn.Sequential(torch.nn.Linear(self.num_states, 32), torch.nn.Tanh(), torch.nn.Linear(32, 1))

    def compute(self, inputs, role=""):
        return self.net(inputs["states"]), {}


def test_mappo_with_the_recipes_policy_and_a_state_critic(recipe):
    """The recipe's shared masked policy under skrl's MAPPO, with one critic on ``env.state()``."""
    env = wrap_env(container_agents_v1.parallel_env("n5_m2_dt60", observation_mode="dict", reward_mode="team",
                                                    state_mode="normalised"))
    agents, policy = env.possible_agents, recipe["shared"]["policy"]
    critic = StateValue(env.state_spaces["container_0"], env.action_spaces["container_0"])
    kwargs = {f.name: {a: {} for a in agents} for f in dataclasses.fields(MAPPO_CFG) if f.name.endswith("_kwargs")}
    mappo = MAPPO(possible_agents=agents, models={a: {"policy": policy, "value": critic} for a in agents},
                  memories={a: RandomMemory(memory_size=32) for a in agents}, observation_spaces=env.observation_spaces,
                  action_spaces=env.action_spaces, state_spaces=env.state_spaces,
                  cfg=MAPPO_CFG(rollouts=32, learning_epochs=1, mini_batches=1, **kwargs))
    trainer = SequentialTrainer(env=env, agents=mappo, cfg={"timesteps": 64, "headless": True,
                                                             "disable_progressbar": True,
                                                             "close_environment_at_exit": False})
    trainer.train()
    for a in agents:
        states = mappo.memories[a].get_tensor_by_name("states").reshape(32, -1)
        assert states.shape == (32, 7) and float(states.max()) <= 2  # the normalised global state
        flat = mappo.memories[a].get_tensor_by_name("observations").reshape(32, -1)
        allowed = unflatten_tensorized_space(recipe["obs_space"], flat)["action_mask"][:, 1] == 1
        actions = mappo.memories[a].get_tensor_by_name("actions").reshape(-1)
        assert not bool((actions[~allowed] == 1).any())  # masks obeyed


def test_skrl_bugs_worked_around_are_still_there(recipe):
    env, agents, cfg = recipe["env"], recipe["agents"], recipe["cfg"]
    models = {a: recipe["shared"] for a in agents}
    spaces = {"observation_spaces": env.observation_spaces, "action_spaces": env.action_spaces}
    # 1. the config's {} defaults for the *_kwargs fields are refused (MultiAgentCfg.expand)
    with pytest.raises(ValueError, match="do not match possible agents"):
        IPPO(possible_agents=agents, models=models, cfg=IPPO_CFG(), state_spaces=env.state_spaces, **spaces)
    # 2. IPPO stores the state although it never uses it: no state_spaces, no memory
    ippo = IPPO(possible_agents=agents, models=models, memories={a: RandomMemory(memory_size=4) for a in agents},
                cfg=dataclasses.replace(cfg), **spaces)
    with pytest.raises(TypeError):
        ippo.init()
    # 3. CategoricalMixin.act passes role by position, so compute(inputs, *, role) as Model declares it fails
    policy = recipe["shared"]["policy"]
    observations, _ = env.reset()
    compute = type(policy).compute
    keyword_only = lambda self, inputs, *, role="": compute(self, inputs, role)  # noqa: E731
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(type(policy), "compute", keyword_only)
        with pytest.raises(TypeError, match="positional"):
            policy.act({"observations": observations["container_0"]}, role="policy")
