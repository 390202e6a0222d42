"""Demonstration datasets: episodes of the rollout planner and of the rule-based controllers on the
built-in plants, for offline RL and imitation (``containergym-marl demonstrations``).

    containergym-marl demonstrations                                   # every test plant, both policies, 100 episodes
    containergym-marl demonstrations --configs n11_m2_dt120 --policies planner --episodes 20 --out datasets

Each (row, policy) gives two datasets, one per view:

* **centralised**: a Minari dataset ``containergym_marl/<row>/<policy>-v0`` written by Minari's own
  :class:`minari.DataCollector` around ``gym.make("containergym_marl/ContainerGym-v0", ...)`` while the
  controller (``planner`` or ``rule_based`` of :data:`~containergym_marl.methods.CONTROLLERS`) acts;
  ``minari.load_dataset`` reads it with ``MINARI_DATASETS_PATH=<out>/minari``, and its environment
  spec rebuilds the plant (``dataset.recover_environment()``).
* **container agents**: ``<out>/agents/<row>/<policy>_agents.npz``, the per-container counterpart of
  the policy (``planner_agents``, ``rule_based_agents``) acting in ``container_agents_v1``, one
  array per field (:data:`AGENT_FIELDS`) readable with NumPy alone (``np.load(path,
  allow_pickle=False)``). Every step also holds ``planner_agents``' decision in that state (its
  *label*), which is the action where the planner acts; :meth:`AgentDemonstrations.dagger_samples`
  gives them as DAgger's (observation, label) pairs.

**Episodes.** :data:`~containergym_marl.evaluation.protocol.DEMONSTRATIONS`: the plant of the paper's
test protocol (δ = 120 s, T = 600, as every evaluation uses) on seeds 40000, 40001, … (``--episodes``
of them, 100 by default), which serve nothing else. The planner is reset with each episode's seed,
as :func:`~containergym_marl.evaluation.evaluate` resets it, so an episode is the one an evaluation
on that seed plays. A δ = 60 s row is tested at δ = 120 s, so its datasets hold the same episodes as
the δ = 120 s row of its plant (only the row's name differs).

**Output folder** (``--out``, default ``datasets/``)::

    <out>/minari/containergym_marl/<row>/<policy>-v0/   Minari datasets (MINARI_DATASETS_PATH=<out>/minari)
    <out>/agents/<row>/<policy>_agents.npz               the container agents' datasets
    <out>/MANIFEST.sha256                                sha256 and size of every file under minari/ and agents/
    <out>/.lock, <out>/.partial/                         the build's lock and the dataset being built

Nothing is written outside it: Minari's collector writes into ``<out>/.partial`` (its
``MINARI_DATASETS_PATH`` while a dataset is built), and a dataset moves into place by a rename when
its last episode is written, so a dataset in ``minari/`` or ``agents/`` is complete. A rerun reuses
the finished datasets (checked against the manifest, and against the episodes asked for: a dataset
of other seeds is an error naming it) and builds the others from their first episode; an
interrupted build leaves only ``.partial``, removed by the next one. One build at a time holds the
folder's lock.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import warnings
import zipfile
import zlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from containergym_marl import ENV_ID, __version__
from containergym_marl.config import list_configs
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation.protocol import DEMONSTRATIONS, EvalProtocol
from containergym_marl.files import atomic_write, open_file, refuse_links, temporary_target
from containergym_marl.manifest import MANIFEST, ManifestError, check_file, read_manifest, write_manifest
from containergym_marl.methods import CONTROLLERS, METHODS
from containergym_marl.options import option, positive_int
from containergym_marl.orchestration.compare_args import PAPER_ROWS

#: The Minari namespace of every dataset: ``containergym_marl/<row>/<policy>-v<VERSION>``.
NAMESPACE = "containergym_marl"
#: The datasets' version (the ``-v0`` of their ids); a change to what an episode holds raises it.
VERSION = 0
#: The policy whose decisions label every container-agent step.
LABELLER = "planner_agents"
#: The demonstrated policies: each centralised controller with a container-agent counterpart (the
#: methods registry's ``counterpart``), and that counterpart; not the shielded planners
#: (``shield_by_default``), whose container-agent steps the labeller (the plain planner) would label
#: with decisions they do not take.
POLICIES: dict[str, str] = {m.counterpart: m.name for m in METHODS.values()
                            if m.controller is not None and m.view == "decentralised" and m.counterpart in CONTROLLERS
                            and not getattr(m.controller, "shield_by_default", False)}
#: The paper rows' distinct plants under the test protocol: a δ = 60 s row is tested at δ = 120 s, on
#: the plant of the δ = 120 s row of the same n and m, so its datasets would repeat that row's.
TEST_PLANTS: tuple[str, ...] = tuple(row for row in PAPER_ROWS if row.endswith("_dt120"))
#: The folders of an output folder that its manifest covers.
FOLDERS = ("minari", "agents")
#: The dataset being built, until it moves into place.
STAGING = ".partial"
DEFAULT_OUT = "datasets"
#: The small dataset the repository ships (n5_m2_dt120, the planner, both views), for tests and recipes.
SHIPPED = "results/datasets"
AUTHOR = "The containergym-marl contributors"
#: Minari's ``code_permalink``: the code that built the datasets (the repository's address is not public yet).
CODE_PERMALINK = f"containergym-marl {__version__}: containergym_marl/demonstrations.py"
AGENTS_FORMAT = "containergym-marl agent demonstrations"
AGENTS_FORMAT_VERSION = 1
#: The arrays of a container-agent dataset: name -> (dtype, shape), N steps of E episodes, n agents,
#: F features (each array's meaning is in docs/demonstrations.md).
AGENT_FIELDS: dict[str, tuple[str, str]] = {
    "observations": ("float32", "N, n, F"),  # what each agent saw before acting
    "actions": ("uint8", "N, n"),  # what it did: 1 requested emptying, 0 waited
    "labels": ("uint8", "N, n"),  # planner_agents' decision in that state (= actions where it acts)
    "rewards": ("float64", "N, n"),  # each agent's own reward (reward_mode="individual")
    "plant_rewards": ("float64", "N"),  # the plant's reward (the team reward, the centralised view's)
    "terminations": ("bool", "N"),  # an overflow ended the episode at this step (all agents together)
    "truncations": ("bool", "N"),  # the time limit T ended it
    "final_observations": ("float32", "E, n, F"),  # each agent's observation after its episode's last step
    "episode_starts": ("int64", "E"),  # the first step of each episode
    "episode_lengths": ("int64", "E"),  # its steps
    "seeds": ("int64", "E"),  # its reset seed
    "metadata": ("str", ""),  # JSON: format, row, policies, environment, protocol, agents, feature names
}


class DemonstrationsError(ValueError):
    """An output folder holds a dataset that is not the one asked for."""


@dataclass
class DemonstrationsArgs:
    """The options of ``containergym-marl demonstrations``."""

    configs: list[str] = option(default_factory=lambda: list(TEST_PLANTS), nargs="+", choices=list_configs,
                                metavar="CONFIG", show_default=False,
                                help=lambda: f"built-in rows, from: {', '.join(list_configs())} (default: the paper "
                                             f"rows' distinct test plants, {' '.join(TEST_PLANTS)})")
    policies: list[str] = option(default_factory=lambda: list(POLICIES), nargs="+", choices=tuple(POLICIES),
                                 metavar="POLICY", show_default=False,
                                 help=f"policies to demonstrate, from: {', '.join(POLICIES)} (default: all); each "
                                      f"gives a centralised Minari dataset and its container agents' dataset "
                                      f"({', '.join(POLICIES.values())})")
    episodes: int = option(DEMONSTRATIONS.episodes, type=positive_int,
                           help=f"episodes per dataset, seeds {DEMONSTRATIONS.first_seed} on (default: "
                                f"{DEMONSTRATIONS.episodes})")
    out: str = option(DEFAULT_OUT, help=f"output folder: minari/ (MINARI_DATASETS_PATH), agents/, {MANIFEST} "
                                        f"(default: {DEFAULT_OUT})")

    def check(self) -> None:
        """Every value known and the output a folder (or nothing yet), checked before anything is
        written; a ValueError naming the option and the value otherwise."""
        configs = list_configs()
        for name in self.configs:
            if name not in configs:
                raise ValueError(f"--configs: unknown config {name!r}; choose from {', '.join(configs)}")
        for name in self.policies:
            if name not in POLICIES:
                raise ValueError(f"--policies: unknown policy {name!r}; choose from {', '.join(POLICIES)}")
        if not self.configs or not self.policies:
            raise ValueError("--configs and --policies: name at least one of each")
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise ValueError(f"--episodes: expected a positive integer, got {self.episodes!r}")
        out = Path(self.out)
        for path in (out, *out.parents):
            if path.exists():
                if not path.is_dir():
                    raise ValueError(f"--out: {str(path)!r} is a file, not a folder; choose a folder for the datasets")
                break

    @property
    def protocol(self) -> EvalProtocol:
        return replace(DEMONSTRATIONS, episodes=self.episodes)


# ---- what a dataset is ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Target:
    """One dataset of an output folder: a (row, policy) in one view (``"centralised"`` or ``"agents"``)."""

    config: str
    policy: str  # the centralised policy's name (planner, rule_based)
    view: str

    @property
    def acting(self) -> str:
        """The method whose episodes it holds: the policy, or its container-agent counterpart."""
        return self.policy if self.view == "centralised" else POLICIES[self.policy]

    @property
    def name(self) -> str:
        """The Minari dataset id, or the container agents' file relative to the output folder."""
        return dataset_id(self.config, self.policy) if self.view == "centralised" else self.relative

    @property
    def relative(self) -> str:
        if self.view == "centralised":
            return f"minari/{dataset_id(self.config, self.policy)}"
        return f"agents/{self.config}/{self.acting}.npz"


def dataset_id(config: str, policy: str) -> str:
    """The Minari id of the centralised dataset of ``policy`` on ``config``."""
    return f"{NAMESPACE}/{config}/{policy}-v{VERSION}"


def agents_path(out: str | Path, config: str, policy: str) -> Path:
    """The container agents' dataset of ``policy`` (a centralised name: planner, rule_based) on ``config``."""
    return Path(out) / Target(config, policy, "agents").relative


def targets(args: DemonstrationsArgs) -> list[Target]:
    """Every dataset asked for, row by row."""
    return [Target(c, p, v) for c in dict.fromkeys(args.configs) for p in dict.fromkeys(args.policies)
            for v in ("centralised", "agents")]


def _protocol_record(protocol: EvalProtocol) -> dict[str, Any]:
    return {"timestep_s": protocol.timestep_s, "episode_length_steps": protocol.episode_length_steps,
            "first_seed": protocol.first_seed, "episodes": protocol.episodes}


def _recorded(out: Path, target: Target) -> dict[str, Any]:
    """What a finished dataset says of itself: its row, policy, protocol and seeds."""
    path = out / target.relative
    try:
        if target.view == "centralised":
            with open_file(path / "data" / "metadata.json", "r", within=out, encoding="utf-8") as f:
                return json.load(f)[NAMESPACE]
        with _npz(path, within=out) as data:
            return json.loads(str(data["metadata"]))  # only this member is read
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DemonstrationsError(f"{path}: not a complete dataset of this package ({exc}); remove it to build it "
                                  f"again") from None


def _files(out: Path, target: Target) -> list[str]:
    path = out / target.relative
    if target.view == "agents":
        return [target.relative]
    return sorted(p.relative_to(out).as_posix() for p in path.rglob("*") if p.is_file())


def finished(out: Path, target: Target, protocol: EvalProtocol, manifest: dict | None) -> bool:
    """Whether ``target`` is built in ``out`` with the episodes of ``protocol``: False when absent;
    a :class:`DemonstrationsError` naming it when it holds other episodes, a ManifestError when a
    file the manifest lists differs from it."""
    path = out / target.relative
    refuse_links(path, out)
    if not path.exists():
        return False
    for name in _files(out, target):  # the bytes first: a changed file is never read further
        if manifest is not None and name in manifest:
            check_file(out, name, manifest)
    recorded = _recorded(out, target)
    if (recorded.get("config"), recorded.get("policy")) != (target.config, target.acting):
        raise DemonstrationsError(f"{path}: holds {recorded.get('policy')!r} on {recorded.get('config')!r}, not "
                                  f"{target.acting!r} on {target.config!r}; remove it to build it again")
    if recorded.get("protocol") != _protocol_record(protocol):
        raise DemonstrationsError(
            f"{path}: holds {recorded.get('protocol', {}).get('episodes')} episodes from seed "
            f"{recorded.get('protocol', {}).get('first_seed')} (δ, T: {recorded.get('protocol')}), not the "
            f"{protocol.episodes} asked for from seed {protocol.first_seed}; remove it or choose another --out")
    return True


# ---- building ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Episode:
    """One demonstrated episode: its seed, steps, plant return and whether an overflow ended it."""

    seed: int
    steps: int
    cumulative_reward: float
    overflow: bool


def _require_minari() -> None:
    from containergym_marl.extras import missing_extra

    try:
        import h5py  # noqa: F401  (Minari's HDF5 storage)
        import jax.tree_util  # noqa: F401  (Minari's DataCollector needs it)
        import minari  # noqa: F401
    except ImportError as exc:
        raise missing_extra("containergym-marl demonstrations (Minari's DataCollector)", "offline", exc) from exc


@contextlib.contextmanager
def minari_root(path: str | Path) -> Iterator[Path]:
    """``MINARI_DATASETS_PATH`` set to ``path`` (absolute) for the block, then restored: where Minari
    reads and writes datasets (``minari.load_dataset``, its collector's temporary files)."""
    path = Path(path).absolute()
    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        yield path
    finally:
        if previous is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous


#: How a dataset's description names a policy of each kind of method.
_KIND_NAMES = {"rule": "rule-based controller", "planner": "rollout planner"}


def _description(target: Target, protocol: EvalProtocol) -> str:
    kind = _KIND_NAMES.get(METHODS[target.policy].kind, "policy")
    return (f"Episodes of containergym-marl's {kind} {target.policy!r} on the ContainerGym "
            f"plant {target.config} under the paper's test protocol (delta = {protocol.timestep_s:g} s, "
            f"T = {protocol.episode_length_steps} steps), {protocol.episodes} episodes with seeds "
            f"{protocol.first_seed}-{protocol.seeds[-1]}, which serve nothing else. Observation: container "
            f"volumes (volume units) and PU timers (seconds); action 0 waits, i empties container i. Built by "
            f"containergym-marl demonstrations.")


def _build_centralised(out: Path, target: Target, protocol: EvalProtocol,
                       on_episode: Callable[[Episode], None]) -> list[Episode]:
    """Run the controller under Minari's DataCollector in ``<out>/.partial`` and move the dataset
    into ``<out>/minari`` when its last episode is written."""
    import gymnasium as gym
    import minari
    from minari.namespace import create_namespace, list_local_namespaces

    staging = out / STAGING / "minari"
    episodes = []
    with minari_root(staging), warnings.catch_warnings():
        # no contact address is published; Minari's collector drops its emptied temporary folder late
        warnings.filterwarnings("ignore", message="`author_email` is set to None")
        warnings.filterwarnings("ignore", message="Implicitly cleaning up", category=ResourceWarning)
        env = gym.make(ENV_ID, config=target.config, timestep_s=protocol.timestep_s,
                       episode_length_steps=protocol.episode_length_steps)
        collector = minari.DataCollector(env, record_infos=False, data_format="hdf5")
        try:
            controller = CONTROLLERS[target.policy](PlantParams.from_config(env.unwrapped.config))
            for seed in protocol.seeds:
                if hasattr(controller, "reset"):  # the planner: seeded per episode, as an evaluation seeds it
                    controller.reset(seed=seed)
                obs, _ = collector.reset(seed=seed)
                total, steps, terminated, truncated = 0.0, 0, False, False
                while not (terminated or truncated):
                    obs, reward, terminated, truncated, _ = collector.step(controller.act(obs, collector))
                    total, steps = total + float(reward), steps + 1
                episodes.append(Episode(seed, steps, total, bool(terminated)))
                on_episode(episodes[-1])
            dataset = collector.create_dataset(
                dataset_id=target.name, eval_env=env.spec, algorithm_name=target.policy, author=AUTHOR,
                code_permalink=CODE_PERMALINK, description=_description(target, protocol),
                requirements=[f"containergym-marl>={__version__}"])
            dataset.storage.update_metadata({NAMESPACE: {
                "config": target.config, "policy": target.acting, "view": "centralised",
                "protocol": _protocol_record(protocol), "seeds": protocol.seeds}})
        finally:
            collector.close()
    final = out / target.relative
    with minari_root(out / "minari"):
        namespace = target.name.rpartition("/")[0]
        if namespace not in list_local_namespaces():
            create_namespace(namespace, description=f"Demonstrations on the ContainerGym plant {target.config} "
                                                    f"(containergym-marl)")
    final.parent.mkdir(parents=True, exist_ok=True)
    os.rename(staging / target.relative.partition("/")[2], final)
    shutil.rmtree(out / STAGING)  # the namespaces' files Minari wrote there
    return episodes


def _build_agents(out: Path, target: Target, protocol: EvalProtocol,
                  on_episode: Callable[[Episode], None]) -> list[Episode]:
    """Run the container agents in ``container_agents_v1``, ``planner_agents`` labelling every step,
    and write the dataset (crash-safe: complete or absent)."""
    from containergym_marl.envs.container_agents_v1 import parallel_env

    env = parallel_env(target.config, timestep_s=protocol.timestep_s,
                       episode_length_steps=protocol.episode_length_steps, reward_mode="individual")
    params = env.simulator.params
    agents = env.possible_agents
    acting = CONTROLLERS[target.acting](params)
    labeller = acting if target.acting == LABELLER else CONTROLLERS[LABELLER](params)
    steps: dict[str, list] = {k: [] for k in ("observations", "actions", "labels", "rewards", "plant_rewards",
                                              "terminations", "truncations")}
    final_observations, episodes = [], []
    for seed in protocol.seeds:
        for policy in {id(p): p for p in (acting, labeller)}.values():
            if hasattr(policy, "reset"):
                policy.reset(seed=seed)
        observations, _ = env.reset(seed=seed)
        total, start = 0.0, len(steps["actions"])
        while env.agents:
            sim = env.simulator
            labels = labeller.decide(sim.state, sim.params).astype(np.uint8)
            if acting is labeller:
                actions = labels
            else:
                chosen = acting.act(observations, env)
                actions = np.array([chosen[a] for a in agents], dtype=np.uint8)
            steps["observations"].append(np.stack([observations[a] for a in agents]))
            observations, rewards, terminations, truncations, infos = env.step(
                {a: int(actions[i]) for i, a in enumerate(agents)})
            steps["actions"].append(actions)
            steps["labels"].append(labels)
            steps["rewards"].append(np.array([rewards[a] for a in agents], dtype=np.float64))
            steps["plant_rewards"].append(infos[agents[0]]["plant_reward"])
            steps["terminations"].append(terminations[agents[0]])
            steps["truncations"].append(truncations[agents[0]])
            total += infos[agents[0]]["plant_reward"]
        final_observations.append(np.stack([observations[a] for a in agents]))
        episodes.append(Episode(seed, len(steps["actions"]) - start, total, bool(steps["terminations"][-1])))
        on_episode(episodes[-1])
    lengths = np.array([e.steps for e in episodes], dtype=np.int64)
    metadata = {
        "format": AGENTS_FORMAT, "version": AGENTS_FORMAT_VERSION, "dataset_version": VERSION,
        "config": target.config, "policy": target.acting, "centralised_policy": target.policy,
        "labeller": LABELLER, "view": "agents", "environment": "container_agents_v1",
        "environment_kwargs": {"config": target.config, "timestep_s": protocol.timestep_s,
                               "episode_length_steps": protocol.episode_length_steps,
                               "reward_mode": "individual", "arbitration": DEFAULT_ARBITRATION},
        "protocol": _protocol_record(protocol), "seeds": protocol.seeds,
        "agents": list(agents), "container_names": list(env.container_names),
        "feature_names": env.feature_names(), "containergym_marl_version": __version__,
    }
    arrays = {
        "observations": np.asarray(steps["observations"], dtype=np.float32),
        "actions": np.asarray(steps["actions"], dtype=np.uint8),
        "labels": np.asarray(steps["labels"], dtype=np.uint8),
        "rewards": np.asarray(steps["rewards"], dtype=np.float64),
        "plant_rewards": np.asarray(steps["plant_rewards"], dtype=np.float64),
        "terminations": np.asarray(steps["terminations"], dtype=bool),
        "truncations": np.asarray(steps["truncations"], dtype=bool),
        "final_observations": np.asarray(final_observations, dtype=np.float32),
        "episode_starts": np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64),
        "episode_lengths": lengths,
        "seeds": np.asarray(protocol.seeds, dtype=np.int64),
        "metadata": np.array(json.dumps(metadata)),
    }

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)

    atomic_write(out / target.relative, write, within=out)
    return episodes


def _clean(out: Path) -> None:
    """What an interrupted build left: the staging folder and atomic writes cut short."""
    if (out / STAGING).exists():
        shutil.rmtree(refuse_links(out / STAGING, out))
    for directory, _folders, files in os.walk(out / "agents"):
        for name in files:
            if temporary_target(name) is not None:
                (Path(directory) / name).unlink()
    for path in out.iterdir():
        if temporary_target(path.name) == MANIFEST and not path.is_symlink():
            path.unlink()


@dataclass(frozen=True)
class Built:
    """A dataset of a build: its target, whether it was built now (else reused) and, when built, its episodes."""

    target: Target
    built: bool
    episodes: tuple[Episode, ...] = ()


def build(args: DemonstrationsArgs, report: Callable[[str], None] = print, show_progress: bool = True) -> list[Built]:
    """Build the datasets ``args`` asks for that ``args.out`` lacks (see the module's docstring); a
    line per dataset to ``report``, a progress bar on stderr (a terminal only). The values are
    checked, and the finished datasets against the manifest and the episodes asked for, before
    anything is written; the manifest is rewritten after every dataset."""
    from containergym_marl.progress_bar import Bar
    from containergym_marl.rundir import RunLock

    args.check()
    _require_minari()
    protocol = args.protocol
    out = Path(args.out)
    asked = targets(args)
    if out.is_dir():  # finished datasets of other episodes, or changed since, refused before the lock is taken
        manifest = _manifest(out)
        for target in asked:
            finished(out, target, protocol, manifest)
    done = []
    with RunLock(out):
        _clean(out)
        manifest = _manifest(out)
        todo = [t for t in asked if not finished(out, t, protocol, manifest)]
        with Bar("demonstrations", len(todo) * protocol.episodes, "episodes", show=show_progress) as bar:
            count = 0
            for target in asked:
                if target not in todo:
                    done.append(Built(target, False))
                    report(f"{target.name}: reused ({protocol.episodes} episodes)")
                    continue

                def on_episode(episode: Episode, target: Target = target) -> None:
                    nonlocal count
                    count += 1
                    bar.advance_to(count, f"{target.config} {target.acting}: seed {episode.seed}, return "
                                          f"{episode.cumulative_reward:.2f}" + (", overflow" if episode.overflow else ""))

                build_one = _build_centralised if target.view == "centralised" else _build_agents
                episodes = build_one(out, target, protocol, on_episode)
                write_manifest(out, FOLDERS)
                done.append(Built(target, True, tuple(episodes)))
                returns = [e.cumulative_reward for e in episodes]
                report(f"{target.name}: {len(episodes)} episodes of {target.acting}, return {np.mean(returns):.2f} "
                       f"± {np.std(returns):.2f}, {sum(e.overflow for e in episodes)} overflowing")
        write_manifest(out, FOLDERS)
        _clean(out)
    report(f"{out / MANIFEST}: sha256 of every dataset file; load the centralised datasets with "
           f"MINARI_DATASETS_PATH={(out / 'minari').absolute()} and minari.load_dataset(ID)")
    return done


def _manifest(out: Path) -> dict | None:
    try:
        return read_manifest(out)
    except ManifestError:
        if (out / MANIFEST).exists():
            raise
        return None


# ---- reading the container agents' datasets ---------------------------------------------------------------
@dataclass(frozen=True)
class AgentDemonstrations:
    """A container agents' dataset (:func:`load_agent_demonstrations`): the arrays of
    :data:`AGENT_FIELDS`, steps of all episodes one after the other, and its metadata."""

    observations: np.ndarray
    actions: np.ndarray
    labels: np.ndarray
    rewards: np.ndarray
    plant_rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    final_observations: np.ndarray
    episode_starts: np.ndarray
    episode_lengths: np.ndarray
    seeds: np.ndarray
    metadata: dict[str, Any]

    @property
    def episodes(self) -> int:
        return int(self.seeds.shape[0])

    def episode(self, index: int) -> dict[str, np.ndarray]:
        """Episode ``index``'s per-step arrays and its final observation."""
        start, length = int(self.episode_starts[index]), int(self.episode_lengths[index])
        steps = slice(start, start + length)
        return {**{k: getattr(self, k)[steps] for k in ("observations", "actions", "labels", "rewards",
                                                         "plant_rewards", "terminations", "truncations")},
                "final_observation": self.final_observations[index]}

    def dagger_samples(self):
        """(observations [N·n, F] float32, labels [N·n] uint8) as torch tensors, every agent's step one
        sample: what :class:`~containergym_marl.training.dagger.Dataset`'s ``add`` takes (the ``train``
        extra's torch)."""
        import torch

        features = self.observations.shape[-1]
        return (torch.from_numpy(self.observations.reshape(-1, features).copy()),
                torch.from_numpy(self.labels.reshape(-1).copy()))


#: What reading a broken zip archive raises, besides ValueError.
_ZIP_ERRORS = (zipfile.BadZipFile, OSError, EOFError, RuntimeError, NotImplementedError, zlib.error, KeyError)
#: The most bytes a container agents' file may unpack to, per byte of the file: the package's files
#: unpack to about 6 (observations are compressed floats); a crafted archive could unpack to gigabytes.
MAX_UNPACK_RATIO = 50


@contextlib.contextmanager
def _npz(path: Path, within: Path | None = None) -> Iterator[Any]:
    """``np.load(path, allow_pickle=False)`` of a ``.npz`` archive that is a regular file (no link
    followed) unpacking to at most :data:`MAX_UNPACK_RATIO` times its size; a ValueError naming the
    file when it is not such an archive or its members are broken (a missing file stays a
    FileNotFoundError)."""
    with open_file(path, "rb", within=within) as f:
        size = os.fstat(f.fileno()).st_size
        try:
            with zipfile.ZipFile(f) as archive:
                unpacked = sum(info.file_size for info in archive.infolist())
                if unpacked > MAX_UNPACK_RATIO * size:
                    raise ValueError(f"{path}: its arrays unpack to {unpacked} bytes, more than {MAX_UNPACK_RATIO} "
                                     f"times the {size} bytes of the file")
                for info in archive.infolist():
                    _check_member(archive, info, path)
        except _ZIP_ERRORS as exc:
            raise ValueError(f"{path}: not a readable NumPy .npz archive ({type(exc).__name__}: {exc})") from None
        f.seek(0)
        try:
            with np.load(f, allow_pickle=False) as data:
                yield data
        except _ZIP_ERRORS as exc:
            raise ValueError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from None


def _check_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path) -> None:
    """An array member declares no more bytes in its header (shape × item size) than the member
    holds, so reading it allocates no more than the archive unpacks to."""
    if not info.filename.endswith(".npy"):
        return
    with archive.open(info) as member:
        try:
            major, _minor = np.lib.format.read_magic(member)
            if major not in (1, 2):
                raise ValueError(f"format version {major}")
            read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
            shape, _order, dtype = read_header(member)
        except (ValueError, TypeError, SyntaxError) as exc:
            raise ValueError(f"{path}: {info.filename} has no NumPy array header ({exc})") from None
    if math.prod(shape) * dtype.itemsize > info.file_size:
        raise ValueError(f"{path}: {info.filename} declares a {shape} {dtype} array, more than its {info.file_size} "
                         f"bytes")


def _read_agents(path: Path, within: Path | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The arrays and metadata of a container agents' dataset, every field checked; a ValueError
    naming the file and the field otherwise. Read with ``allow_pickle=False``: data never runs code."""
    try:
        with _npz(path, within) as data:
            missing = sorted(set(AGENT_FIELDS) - set(data.files))
            if missing:
                raise ValueError(f"not a container agents' dataset (no {', '.join(missing)})")
            arrays = {k: data[k] for k in AGENT_FIELDS}
        metadata = json.loads(str(arrays.pop("metadata")))
    except ValueError as exc:  # an object array is refused, never unpickled
        raise ValueError(exc if str(exc).startswith(str(path)) else f"{path}: {exc}") from None
    if not isinstance(metadata, dict) or (metadata.get("format"), metadata.get("version")) != (
            AGENTS_FORMAT, AGENTS_FORMAT_VERSION):
        raise ValueError(f"{path}: not a container agents' dataset of version {AGENTS_FORMAT_VERSION}")
    for name, (dtype, _shape) in AGENT_FIELDS.items():
        if name != "metadata" and arrays[name].dtype != np.dtype(dtype):
            raise ValueError(f"{path}: {name} is {arrays[name].dtype}, expected {dtype}")
    obs, lengths = arrays["observations"], arrays["episode_lengths"]
    if obs.ndim != 3:
        raise ValueError(f"{path}: observations have shape {obs.shape}, expected (N, n, F)")
    if arrays["seeds"].ndim != 1:
        raise ValueError(f"{path}: seeds have shape {arrays['seeds'].shape}, expected (E,)")
    steps, agents, features = obs.shape
    episodes = arrays["seeds"].shape[0]
    expected = {"actions": (steps, agents), "labels": (steps, agents), "rewards": (steps, agents),
                "plant_rewards": (steps,), "terminations": (steps,), "truncations": (steps,),
                "final_observations": (episodes, agents, features), "episode_starts": (episodes,),
                "episode_lengths": (episodes,)}
    for name, shape in expected.items():
        if arrays[name].shape != shape:
            raise ValueError(f"{path}: {name} has shape {arrays[name].shape}, expected {shape}")
    if lengths.sum() != steps or np.any(lengths < 1) or not np.array_equal(
            arrays["episode_starts"], np.concatenate([[0], np.cumsum(lengths)[:-1]])):
        raise ValueError(f"{path}: episode_starts and episode_lengths do not split its {steps} steps into episodes")
    for name in ("actions", "labels"):
        if arrays[name].size and arrays[name].max() > 1:
            raise ValueError(f"{path}: {name} must be 0 or 1 (the two actions)")
    if not (np.isfinite(obs).all() and np.isfinite(arrays["final_observations"]).all()):
        raise ValueError(f"{path}: its observations are not all finite")
    return arrays, metadata


def load_agent_demonstrations(path: str | Path) -> AgentDemonstrations:
    """A container agents' dataset (``<out>/agents/<row>/<policy>_agents.npz``), checked field by
    field (a ValueError naming the file and the field)."""
    arrays, metadata = _read_agents(Path(path))
    return AgentDemonstrations(**arrays, metadata=metadata)


__all__ = ["AGENT_FIELDS", "DEMONSTRATIONS", "LABELLER", "NAMESPACE", "POLICIES", "SHIPPED", "AgentDemonstrations",
           "Built", "DemonstrationsArgs", "DemonstrationsError", "Episode", "Target", "agents_path", "build",
           "dataset_id", "finished", "load_agent_demonstrations", "minari_root", "targets"]
