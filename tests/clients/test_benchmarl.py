"""BenchMARL on ContainerGym (``containergym_marl.training.benchmarl_task``): MAPPO, IPPO and QMIX
experiments run a few iterations on the batched TorchRL environment, save a checkpoint that
reloads, and the trained policy respects the action masks and is evaluated with the paper's
protocol through :func:`~containergym_marl.evaluation.evaluate`.

Needs benchmarl (skipped without it; the ``clients`` extra installs it). MAPPO takes ~10 s with
one torch thread and is in the default run; IPPO and QMIX are ``slow``.
"""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("benchmarl")
from benchmarl.algorithms import IppoConfig, MappoConfig, QmixConfig  # noqa: E402
from benchmarl.experiment import Experiment, ExperimentConfig  # noqa: E402
from benchmarl.models.mlp import MlpConfig  # noqa: E402

from containergym_marl import list_configs, load_config  # noqa: E402
from containergym_marl.envs.torchrl_env import GROUP  # noqa: E402
from containergym_marl.evaluation import EvalProtocol, evaluate  # noqa: E402
from containergym_marl.policies.torchrl_policy import TorchRLAgentsPolicy  # noqa: E402
from containergym_marl.training.benchmarl_task import DEFAULT_TASK_CONFIG, ContainerGymTask  # noqa: E402

T = 40  # short episodes: evaluation rollouts end within an iteration


@pytest.fixture
def one_torch_thread():
    """BenchMARL's small networks run fastest on one thread; more threads stall on a busy 2-core
    machine (a 2-iteration MAPPO run went from ~30 s to ~8 s)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _experiment(algorithm, folder, iters=2) -> Experiment:
    cfg = ExperimentConfig.get_from_yaml()
    cfg.max_n_iters, cfg.max_n_frames = iters, None
    cfg.on_policy_collected_frames_per_batch = cfg.off_policy_collected_frames_per_batch = 8 * T
    cfg.on_policy_n_envs_per_worker = cfg.off_policy_n_envs_per_worker = 8
    cfg.on_policy_n_minibatch_iters, cfg.on_policy_minibatch_size = 2, 80
    cfg.off_policy_n_optimizer_steps, cfg.off_policy_train_batch_size = 4, 64
    cfg.evaluation, cfg.evaluation_interval, cfg.evaluation_episodes = True, 8 * T, 3
    cfg.loggers, cfg.render, cfg.create_json = ["csv"], False, False
    cfg.save_folder, cfg.checkpoint_at_end = str(folder), True
    task = ContainerGymTask.N5_M2_DT120.get_task(config={**DEFAULT_TASK_CONFIG, "episode_length_steps": T})
    model = MlpConfig(num_cells=[32, 32], layer_class=torch.nn.Linear, activation_class=torch.nn.Tanh)
    return Experiment(task=task, algorithm_config=algorithm.get_from_yaml(), model_config=model,
                      critic_model_config=model, seed=0, config=cfg)


def test_tasks_cover_the_builtin_configs():
    assert sorted(t.name.lower() for t in ContainerGymTask) == sorted(list_configs())
    task = ContainerGymTask.N11_M2_DT120.get_task()
    assert task.config == DEFAULT_TASK_CONFIG and task.env_name() == "containergym"
    env = task.get_env_fun(num_envs=3, continuous_actions=False, seed=0, device="cpu")()
    assert env.batch_size == (3,) and env.n_agents == 11 and env.reward_mode == "team"
    assert task.group_map(env) == {GROUP: [f"container_{i}" for i in range(11)]}
    assert list(task.observation_spec(env)[GROUP].keys()) == ["observation"]
    assert list(task.action_mask_spec(env)[GROUP].keys()) == ["action_mask"]
    assert list(task.state_spec(env).keys()) == ["state"] and task.state_spec(env)["state"].shape == (13,)
    assert task.max_steps(env) == load_config("n11_m2_dt120").episode_length_steps and not task.supports_continuous_actions()


def _check_trained(experiment, tmp_path):
    assert experiment.n_iters_performed == 2 and experiment.total_frames == 2 * 8 * T
    # the trained policy never requests while no PU is free (the masks reach the policy)
    env = ContainerGymTask.N5_M2_DT120.get_task(config={**DEFAULT_TASK_CONFIG, "episode_length_steps": T}) \
        .get_env_fun(num_envs=16, continuous_actions=False, seed=1, device="cpu")()
    rollout = env.rollout(T, policy=experiment.policy, break_when_any_done=False)
    blocked = ~rollout[GROUP, "action_mask"][..., 1]
    assert blocked.any() and not rollout[GROUP, "action"][blocked].any()
    # the checkpoint reloads, and the reloaded policy is evaluated with the paper's protocol
    checkpoint = next((tmp_path / experiment.folder_name.name / "checkpoints").glob("*.pt"))
    reloaded = Experiment.reload_from_file(str(checkpoint))
    result = evaluate(TorchRLAgentsPolicy(reloaded.policy, name="mappo"), "n5_m2_dt120",
                      EvalProtocol(episodes=2, episode_length_steps=50))
    assert len(result.episodes) == 2 and all(e.steps > 0 for e in result.episodes)
    first = evaluate(TorchRLAgentsPolicy(experiment.policy), "n5_m2_dt120", EvalProtocol(episodes=2, episode_length_steps=50))
    assert first.returns.tolist() == result.returns.tolist()


def test_mappo_runs_saves_and_evaluates(tmp_path, one_torch_thread):
    experiment = _experiment(MappoConfig, tmp_path)
    experiment.run()
    # MAPPO's critic reads the global state
    assert experiment.state_spec is not None and "state" in experiment.state_spec.keys()
    _check_trained(experiment, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", [IppoConfig, QmixConfig], ids=["ippo", "qmix"])
def test_other_algorithms_run(algorithm, tmp_path, one_torch_thread):
    experiment = _experiment(algorithm, tmp_path)
    experiment.run()
    _check_trained(experiment, tmp_path)
