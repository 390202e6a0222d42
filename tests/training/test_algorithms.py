"""The algorithm registry: one entry per algorithm, read by training, evaluation and the CLI."""

from __future__ import annotations

import dataclasses
import math
import warnings

import pytest

from containergym_marl import load_config
from containergym_marl.cli import build_parser
from containergym_marl.policies import CentralisedModelPolicy, SharedModelPolicy
from containergym_marl.training import ALGORITHMS, REGISTRY, get_algorithm
from containergym_marl.algorithms import rollout_steps


def test_registry_entries_load_their_classes_and_views():
    from sb3_contrib import TRPO, MaskablePPO
    from stable_baselines3 import DQN, PPO

    classes = {"ppo": PPO, "trpo": TRPO, "dqn": DQN, "maskable_ppo": MaskablePPO, "shared_ppo": PPO}
    native = ("fast_ppo", "fast_shared_ppo", "fast_shared_ppo_checked", "dagger_agents", "dagger_ppo_agents", "dagger_response_agents",
              "dagger_contended_agents", "dagger_dapg_agents", "dagger_checked_agents", "dagger_messaging_agents")
    assert set(ALGORITHMS) == set(classes) | set(native)
    for name, cls in classes.items():
        assert get_algorithm(name).load_class() is cls
    for name in native:  # tensor-only files
        spec = get_algorithm(name)
        assert spec.native and not spec.sb3 and spec.model_file("best") == "best_model.pt"
        with pytest.raises(ValueError, match="not a Stable-Baselines3 algorithm"):
            spec.load_class()
    assert get_algorithm("fast_shared_ppo").method_name("team") == "fast_shared_ppo_team"
    from containergym_marl.training import dagger, fast_ppo

    trainers = [get_algorithm(a).trainer() for a in native]
    assert trainers == [fast_ppo.TRAINER, fast_ppo.TRAINER, fast_ppo.CHECKED_TRAINER, dagger.IMITATION,
                        dagger.IMITATION_THEN_PPO, dagger.RESPONSE_IMITATION, dagger.CONTENDED_IMITATION,
                        dagger.IMITATION_THEN_DAPG, dagger.CHECKED_IMITATION, dagger.MESSAGING_IMITATION]
    assert fast_ppo.TRAINER.settings({}).own_check() is None  # the plain PPO has no check unless told
    assert fast_ppo.CHECKED_TRAINER.settings({}).own_check() == {"risk": 1e-4, "lead_steps": 1}
    assert fast_ppo.CHECKED_TRAINER.settings({"own_check_risk": 1e-3}).own_check()["risk"] == 1e-3  # --hp wins
    imitations = trainers[3:-1]  # the messaging imitation: the checked one with the shared check, below
    assert not dagger.IMITATION.fine_tune and dagger.IMITATION_THEN_PPO.fine_tune
    assert [t.settings({}).labels for t in imitations] == ["planner"] * 2 + ["response"] + ["planner"] * 3
    assert [t.settings({}).contended_share for t in imitations] == [0.0, 0.0, 0.0, dagger.CONTENDED_SHARE, 0.0, 0.0]
    # the imitation of the reference: the shielded planner's labels (ε = 1e-6) and the agents' own check
    # (ε = 1e-4, a lead of one fill), which only it of the imitations carries unless told
    assert [(t.settings({}).safety_risk, t.settings({}).own_check()) for t in imitations] == (
        [(0.0, None)] * 5 + [(1e-6, {"risk": 1e-4, "lead_steps": 1})])
    assert not dagger.CHECKED_IMITATION.fine_tune and dagger.CHECKED_IMITATION.settings({}).greedy
    # and its greedy rule: a request above 0.3, which the others make above 0.5 (their most likely action)
    assert [t.settings({}).model_threshold() for t in imitations if not t.fine_tune] == [None, None, None, 0.3]
    assert dagger.CHECKED_IMITATION.settings({"request_threshold": 0.5}).model_threshold() is None  # --hp wins
    assert [t.settings({}).bc_coef for t in imitations[1::3]] == [0.0, dagger.DAPG_SETTINGS["bc_coef"]]
    assert dagger.IMITATION_THEN_DAPG.fine_tune and dagger.IMITATION_THEN_DAPG.settings({}).ppo is not None
    assert dagger.CONTENDED_IMITATION.settings({"contended_share": 0.25}).contended_share == 0.25  # --hp wins
    # the messaging imitation: the checked imitation's settings, and the shared check the screen chose
    messaging = dagger.MESSAGING_IMITATION.settings({})
    assert dataclasses.replace(messaging, shared_check_risk=0.0) == dagger.CHECKED_IMITATION.settings({})
    assert messaging.shared_check() == {"risk": 1e-4, "window_steps": 24, "prefer": "policy"}
    assert all(t.settings({}).shared_check() is None for t in imitations)
    with pytest.raises(ValueError, match="not trained by a native trainer"):
        get_algorithm("ppo").trainer()
    assert get_algorithm("dagger_agents").policy_adapter is get_algorithm("fast_shared_ppo").policy_adapter
    assert get_algorithm("shared_ppo").policy_adapter is SharedModelPolicy
    assert all(REGISTRY[a].policy_adapter is CentralisedModelPolicy for a in ("ppo", "trpo", "dqn", "maskable_ppo"))
    assert get_algorithm("dqn").replay_buffer and not get_algorithm("ppo").replay_buffer
    assert get_algorithm("dqn").default_n_envs == 1 and get_algorithm("ppo").default_n_envs == 8
    with pytest.raises(ValueError, match="unknown algorithm 'a2c'"):
        get_algorithm("a2c")


def test_cli_choices_come_from_the_registry():
    train = build_parser()._subparsers._group_actions[0].choices["train"]
    algo = next(a for a in train._actions if a.dest == "algo")
    assert tuple(algo.choices) == ALGORITHMS


def test_centralised_rollouts_keep_the_papers_6144_samples():
    """The settings of the published runs: n_steps = 6144 / n_envs, minibatch 64, fused Adam."""
    kwargs = get_algorithm("ppo").kwargs(8)
    assert kwargs == {"gamma": 0.99, "n_steps": 768, "batch_size": 64,
                      "policy_kwargs": {"optimizer_kwargs": {"fused": True, "eps": 1e-5}}}
    for slots in (1, 2, 4, 8, 16, 32, 64):
        assert rollout_steps(slots) == 6144 // slots
    assert "n_steps" not in get_algorithm("dqn").kwargs(1)


def test_rollout_buffer_is_the_divisible_size_nearest_to_6144():
    for slots in range(1, 400):
        n = rollout_steps(slots)
        assert (n * slots) % 64 == 0, slots
        # no other multiple of k (the n_steps with a divisible buffer) is nearer to 6144 samples
        k = 64 // math.gcd(slots, 64)
        assert n % k == 0 and n >= 2, slots
        if n > k:
            assert abs(n * slots - 6144) <= abs((n - k) * slots - 6144), slots
        assert abs(n * slots - 6144) <= abs((n + k) * slots - 6144), slots


def test_shared_ppo_rollout_sizes_and_no_sb3_minibatch_warning():
    """Shared PPO, 8 simulations: n=5 gives 40 slots, n_steps 152 (6080 samples); n=11 gives 88
    slots, 72 (6336). SB3 warns when the minibatch does not divide the buffer (153 x 40 = 6120 did)."""
    from stable_baselines3 import PPO

    from containergym_marl.envs.vector import ContainerAgentsVecEnv

    spec = get_algorithm("shared_ppo")
    for config, n_steps in (("n5_m2_dt120", 152), ("n11_m2_dt120", 72)):
        slots = spec.num_slots(load_config(config).n_containers, 8)
        kwargs = spec.kwargs(slots)
        assert kwargs["n_steps"] == n_steps
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            PPO("MlpPolicy", ContainerAgentsVecEnv(config, 8), device="cpu", **kwargs)
        assert not [w for w in caught if "mini-batch" in str(w.message)], [str(w.message) for w in caught]


def test_hyperparams_override_the_registry_settings():
    spec = get_algorithm("ppo")
    kwargs = spec.kwargs(40, hyperparams={"batch_size": 128, "learning_rate": 1e-4})
    assert kwargs["batch_size"] == 128 and kwargs["learning_rate"] == 1e-4
    assert (kwargs["n_steps"] * 40) % 128 == 0  # the rollout fits the caller's minibatch
    assert spec.kwargs(8, hyperparams={"n_steps": 100})["n_steps"] == 100
