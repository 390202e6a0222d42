"""Environment and training throughput, measured side by side in one run on this machine.

Run from the repository root (the package importable, with its training extra for the PPO part)::

    python benchmarks/throughput.py                          # ours alone, about 1.5 minutes
    python benchmarks/throughput.py --reference-python REFVENV/bin/python --compare-with ../old-checkout
    python benchmarks/throughput.py --json out.json          # also write every number as JSON
    python benchmarks/throughput.py --smoke                  # tiny sizes, seconds (what the tests run)

What is measured (an *env step* is one step of one simulated plant; an *agent step* one step of one
container agent, n per env step):

1. **B = 1**: the centralised Gymnasium env (``ContainerGymEnv``), its ``reset()`` alone, and the
   PettingZoo ``parallel_env`` (dict API) at n = 5 (``n5_m2_dt120``) and n = 11 (``n11_m2_dt120``),
   random actions with resets included. Beside them, in the same run:

   * the **earlier implementation itself** (``../shared/reference-impl``: the paper's code, old
     ``gym`` 0.26.2 API, global ``np.random``) with the same plants from
     ``../shared/reference-configs`` (``5containers_2presses_2.json``, ``11containers_2presses_3.json``).
     It runs in its own virtual environment (``numpy matplotlib gym==0.26.2``; never a dependency
     of this package), named by ``--reference-python`` or ``CONTAINERGYM_REFERENCE_PYTHON``;
     without one its columns are left out;
   * another checkout of this package (``--compare-with PATH``, imported with ``PYTHONPATH=PATH``),
     e.g. the code before a change, for before/after ratios.
2. **Vectorised envs at B = 4096**: ``ContainerGymVecEnv`` and the Gymnasium vector env of
   ``gym.make_vec(..., vectorization_mode="vector_entry_point")`` (env steps/s), and
   ``ContainerAgentsVecEnv`` (agent steps/s), n = 5 and 11.
3. **Where the time goes at B = 1** (ours only): timers around the compiled kernel, the Python
   around it in the core (input checks, output arrays, random rows, bookkeeping), the
   observations, the view (action, rewards and infos) and the resets.
4. **SB3 PPO** (ours only, ``n5_m2_dt120``, the package's training settings): samples/s and the
   share of wall time spent in the environment (``step_wait``).
5. The issue's **targets**, judged on the numbers of this run.

Every implementation runs in its own worker process (this script with ``--worker``, answering one
JSON request per line), so each imports its own code. The timed bursts alternate between the
workers, round after round, and every ratio is the median over rounds of the ratio of two bursts
taken one after the other: ratios from one run are meaningful on a busy machine, single rates much
less so. Beside the wall-clock rates, ours is also shown per CPU-second of its worker (all threads):
it leaves out the time the worker waited for a core while other jobs ran, so for the
single-threaded B = 1 paths it approximates an idle machine's rate, and for the threaded
vectorised step an idle machine's wall-clock rate is at most (number of cores) × it. Actions are
drawn in advance from a fixed seed, identically for every implementation: the
centralised controller asks to empty a uniformly chosen container with probability 0.15 and waits
otherwise; each container agent requests with probability 0.15.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np  # the only import outside the standard library: the reference venv runs this file too

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
#: n -> (this package's config, the earlier implementation's config file)
CONFIGS = {5: ("n5_m2_dt120", "5containers_2presses_2.json"), 11: ("n11_m2_dt120", "11containers_2presses_3.json")}
EMPTY_PROBABILITY = 0.15
PPO_CONFIG = "n5_m2_dt120"
OURS, REFERENCE = "ours", "reference"
REFERENCE_ENV_VAR = "CONTAINERGYM_REFERENCE_PYTHON"


@dataclass(frozen=True)
class Case:
    key: str  # the path measured: gym, reset, pettingzoo, vec, vec_agents
    n: int
    batch: int

    @property
    def id(self) -> str:
        return f"{self.key}-n{self.n}-B{self.batch}"


@dataclass(frozen=True)
class Sizes:
    vec_batch: int
    burst_s: float  # length of one timed burst
    rounds: int  # bursts per case and implementation
    profile_steps: int
    ppo_sims: int
    ppo_updates: int
    ppo_n_steps: int | None  # None: the package's rollout length


FULL = Sizes(vec_batch=4096, burst_s=0.25, rounds=7, profile_steps=20000, ppo_sims=8, ppo_updates=2, ppo_n_steps=None)
SMOKE = Sizes(vec_batch=8, burst_s=0.01, rounds=2, profile_steps=200, ppo_sims=2, ppo_updates=1, ppo_n_steps=16)

LABELS = {
    "gym": "centralised env step (ContainerGymEnv)",
    "reset": "reset() alone (ContainerGymEnv)",
    "pettingzoo": "PettingZoo parallel_env step (dict API)",
    "vec": "ContainerGymVecEnv (SB3)",
    "vec_gymnasium": "ContainerGymVectorEnv (Gymnasium make_vec)",
    "vec_agents": "ContainerAgentsVecEnv (SB3)",
}


def cases_for(sizes: Sizes) -> list[Case]:
    b1 = [Case(key, n, 1) for key in ("gym", "reset", "pettingzoo") for n in CONFIGS]
    return b1 + [Case(key, n, sizes.vec_batch) for key in ("vec", "vec_gymnasium", "vec_agents") for n in CONFIGS]


# ================================================================================================
# Worker side: runs inside the measured implementation's own process (and Python environment).
# ================================================================================================
def central_actions(n: int, count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    empty = rng.random(count) < EMPTY_PROBABILITY
    return np.where(empty, rng.integers(1, n + 1, count), 0)


def agent_actions(n: int, count: int, seed: int = 0) -> np.ndarray:
    return (np.random.default_rng(seed).random((count, n)) < EMPTY_PROBABILITY).astype(np.int64)


class Runner:
    """``run(k)`` makes k calls of one path; ``steps_per_call`` env steps each."""

    def __init__(self, run, steps_per_call: int, episodes: dict | None = None):
        self.run, self.steps_per_call, self.episodes = run, steps_per_call, episodes
        self.calls = 1


def _single_env_loop(step, reset, actions: list, episodes: dict):
    """k steps of a B = 1 env, resetting when ``step`` says the episode ended."""
    state = {"t": 0}

    def run(k):
        t = state["t"]
        for i in range(k):
            if step(actions[(t + i) % len(actions)]):
                reset()
                episodes["resets"] += 1
        state["t"] = t + k
        episodes["steps"] += k
    return run


def package_runner(case: Case) -> Runner:
    """A runner of this package (whichever checkout is on PYTHONPATH), built as a user would."""
    from containergym_marl import ContainerGymEnv, container_agents_v0
    from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv

    name, n, batch = CONFIGS[case.n][0], case.n, case.batch
    episodes = {"steps": 0, "resets": 0}
    # resets go through ``lambda: env.reset()`` (looked up at call time), so that the profile's
    # timer on the env class sees them
    if case.key in ("gym", "reset"):
        env = ContainerGymEnv(name)
        env.reset(seed=0)
        if case.key == "reset":
            def run(k):
                for _ in range(k):
                    env.reset()
            return Runner(run, 1)

        def step(a):
            _, _, terminated, truncated, _ = env.step(a)
            return terminated or truncated
        return Runner(_single_env_loop(step, lambda: env.reset(), central_actions(n, 4096).tolist(), episodes),
                      1, episodes)
    if case.key == "pettingzoo":
        env = container_agents_v0.parallel_env(config=name)
        env.reset(seed=0)
        agents = env.possible_agents
        actions = [dict(zip(agents, row)) for row in agent_actions(n, 4096).tolist()]

        def step(a):
            env.step(a)
            return not env.agents
        return Runner(_single_env_loop(step, lambda: env.reset(), actions, episodes), 1, episodes)
    if case.key == "vec":
        venv = ContainerGymVecEnv(name, num_envs=batch)
        actions = [central_actions(n, batch, seed) for seed in range(64)]
    elif case.key == "vec_gymnasium":  # its own step API: infos as arrays, autoreset in the same step
        import gymnasium

        genv = gymnasium.make_vec("containergym_marl/ContainerGym-v0", num_envs=batch,
                                  vectorization_mode="vector_entry_point", config=name)
        genv.reset(seed=0)
        actions = [central_actions(n, batch, seed) for seed in range(64)]
        state = {"t": 0}

        def run_gymnasium(k):
            t = state["t"]
            for i in range(k):
                genv.step(actions[(t + i) % 64])
            state["t"] = t + k
        return Runner(run_gymnasium, batch)
    elif case.key == "vec_agents":
        venv = ContainerAgentsVecEnv(name, num_sims=batch)
        actions = [agent_actions(n, batch, seed).reshape(-1) for seed in range(64)]
    else:
        raise KeyError(case.key)
    venv.seed(0)
    venv.reset()
    state = {"t": 0}

    def run(k):
        t = state["t"]
        for i in range(k):
            venv.step_async(actions[(t + i) % 64])
            venv.step_wait()
        state["t"] = t + k
    return Runner(run, batch)


def reference_runner(case: Case, configs_dir: str) -> Runner:
    """A runner of the earlier implementation (``containergym.env.ContainerEnv``, gym 0.26.2 API)."""
    from containergym.env import ContainerEnv

    if case.key not in ("gym", "reset") or case.batch != 1:
        raise KeyError(f"the earlier implementation has no {case.key!r} path")
    env = ContainerEnv.from_json(str(Path(configs_dir) / CONFIGS[case.n][1]))
    np.random.seed(0)  # it draws from the global np.random
    env.reset()
    if case.key == "reset":
        def run(k):
            for _ in range(k):
                env.reset()
        return Runner(run, 1)
    episodes = {"steps": 0, "resets": 0}
    return Runner(_single_env_loop(lambda a: env.step(a)[2], env.reset, central_actions(case.n, 4096).tolist(),
                                   episodes), 1, episodes)


def calibrate(runner: Runner, burst_s: float) -> None:
    """Warm up (first calls compile or fill caches), then size one burst to about ``burst_s``."""
    runner.run(3)
    calls = 1
    while True:
        t = time.perf_counter()
        runner.run(calls)
        dt = time.perf_counter() - t
        if dt >= burst_s / 4 or calls >= 1 << 22:
            break
        calls *= 2
    runner.calls = max(1, round(calls * burst_s / max(dt, 1e-9)))


class _Timers:
    """Timers around functions looked up at call time (module or class attributes). A timer marked
    ``exclusive`` (the resets) stops the others while it runs."""

    def __init__(self):
        self.spent: dict[str, float] = {}
        self._paused = False
        self._undo: list = []

    def timed(self, label: str, inner, exclusive: bool = False):
        spent = self.spent
        spent.setdefault(label, 0.0)

        def timed(*args, **kwargs):
            if self._paused:
                return inner(*args, **kwargs)
            self._paused = exclusive
            t = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                spent[label] += time.perf_counter() - t
                if exclusive:
                    self._paused = False
        return timed

    def wrap(self, owner, name: str, label: str, exclusive: bool = False):
        inner = getattr(owner, name)
        setattr(owner, name, self.timed(label, inner, exclusive))
        self._undo.append((owner, name, inner))

    def restore(self):
        for owner, name, inner in reversed(self._undo):
            setattr(owner, name, inner)


def profile_b1(key: str, n: int, steps: int) -> dict:
    """µs per step of one B = 1 path, split by timers around the core's functions (this checkout's
    structure: one compiled kernel per arbitration rule, called by ``dynamics.step_checked``)."""
    import dataclasses

    from containergym_marl.core.observations import AgentObservations
    from containergym_marl import ContainerAgentsParallelEnv, ContainerGymEnv
    from containergym_marl.core import dynamics
    from containergym_marl.core.rng import NoiseStreams
    from containergym_marl.core.simulator import PlantSimulator

    case = Case(key, n, 1)
    plain = package_runner(case)
    calibrate(plain, 0.05)
    t = time.perf_counter()
    plain.run(steps)
    untimed = (time.perf_counter() - t) / steps

    timers = _Timers()
    rule = dynamics.get_rule("fullest")
    kernel = timers.timed("kernel", rule.step_batch)
    dynamics.ARBITRATION_RULES["fullest"] = dataclasses.replace(rule, step_batch=kernel)
    try:
        # built after the patch: a simulator takes its rule (and so the kernel) when it is built
        runner = package_runner(case)
        runner.run(3)
        timers.spent.update(dict.fromkeys(timers.spent, 0.0))
        timers.wrap(dynamics, "step_checked", "core step")  # what the simulator calls
        timers.wrap(NoiseStreams, "next_rows", "random rows")
        timers.wrap(PlantSimulator, "step", "simulator step")
        for env_class in (ContainerGymEnv, ContainerAgentsParallelEnv):
            timers.wrap(env_class, "reset", "resets", exclusive=True)
        timers.wrap(PlantSimulator, "global_state", "observations")
        timers.wrap(AgentObservations, "__call__", "observations")  # the agents' view builds them here
        t = time.perf_counter()
        runner.run(steps)
        total = time.perf_counter() - t
    finally:
        dynamics.ARBITRATION_RULES["fullest"] = rule
        timers.restore()
    s = {k: v / steps * 1e6 for k, v in timers.spent.items()}
    parts = {
        "kernel": s["kernel"],
        "core around the kernel": s["core step"] - s["kernel"],
        "random rows": s["random rows"],
        "simulator bookkeeping": s["simulator step"] - s["core step"] - s["random rows"],
        "observations": s["observations"],
        "view (actions, rewards, infos)": total / steps * 1e6 - s["simulator step"] - s["observations"] - s["resets"],
        "resets": s["resets"],
    }
    return {"path": key, "n": n, "untimed_us": untimed * 1e6, "timed_us": total / steps * 1e6, "parts_us": parts}


def ppo_throughput(algo: str, sims: int, updates: int, n_steps: int | None) -> dict:
    """Samples/s of ``model.learn`` with the package's settings for ``algo``, and the share of that
    wall time spent in the environment (``step_wait``)."""
    import torch
    from stable_baselines3 import PPO

    from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv
    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.training.loop import _no_distribution_validation

    torch.set_num_threads(1)
    spec = get_algorithm(algo)
    venv = (ContainerAgentsVecEnv(PPO_CONFIG, num_sims=sims) if spec.view == "decentralised"
            else ContainerGymVecEnv(PPO_CONFIG, num_envs=sims))
    venv.seed(0)
    kwargs = spec.kwargs(venv.num_envs)
    if n_steps is not None:
        kwargs["n_steps"], kwargs["batch_size"] = n_steps, min(kwargs["batch_size"], n_steps * venv.num_envs)
    spent = [0.0]
    inner = venv.step_wait

    def step_wait():
        t = time.perf_counter()
        try:
            return inner()
        finally:
            spent[0] += time.perf_counter() - t
    venv.step_wait = step_wait
    model = PPO("MlpPolicy", venv, device="cpu", verbose=0, seed=0, **kwargs)
    t = time.perf_counter()
    with _no_distribution_validation():
        model.learn(updates * kwargs["n_steps"] * venv.num_envs)
    wall = time.perf_counter() - t
    venv.close()
    rate = model.num_timesteps / wall
    return {"algo": algo, "slots": venv.num_envs, "n_steps": kwargs["n_steps"], "samples": model.num_timesteps,
            "wall_s": wall, "samples_per_s": rate, "env_share": spent[0] / wall, "projected_2M_min": 2e6 / rate / 60}


def worker_info(kind: str) -> dict:
    info = {"python": platform.python_version(), "numpy": np.__version__, "executable": sys.executable}
    if kind == "reference":
        import gym

        import containergym
        info.update(gym=gym.__version__, module=str(Path(containergym.__file__).parent))
    else:
        import containergym_marl
        info["module"] = str(Path(containergym_marl.__file__).parent)
        from containergym_marl.core import dynamics
        info["parallel_min_batch"] = getattr(dynamics, "PARALLEL_MIN_BATCH", None)
        try:
            import numba
            info["numba"] = numba.__version__
        except ImportError:
            info["numba"] = "not installed"
    return info


def worker_main(kind: str) -> None:
    """Answer one JSON request per line on stdin. Anything the measured code prints goes to
    stderr, so stdout carries the answers only."""
    answers = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    import warnings
    warnings.simplefilter("ignore")
    runners: dict[str, Runner] = {}
    for line in sys.stdin:
        request = json.loads(line)
        op = request["op"]
        try:
            if op == "quit":
                break
            if op == "info":
                answer = worker_info(kind)
            elif op == "setup":
                case = Case(request["key"], request["n"], request["batch"])
                runner = (reference_runner(case, request["configs_dir"]) if kind == "reference"
                          else package_runner(case))
                calibrate(runner, request["burst_s"])
                runners[case.id] = runner
                answer = {"calls": runner.calls}
            elif op == "burst":
                runner = runners[request["case"]]
                steps = runner.calls * runner.steps_per_call
                t, cpu = time.perf_counter(), time.process_time()
                runner.run(runner.calls)
                cpu, t = time.process_time() - cpu, time.perf_counter() - t
                answer = {"rate": steps / t, "cpu_rate": steps / max(cpu, 1e-9)}
            elif op == "episodes":
                answer = {cid: r.episodes for cid, r in runners.items() if r.episodes}
            elif op == "profile":
                answer = profile_b1(request["key"], request["n"], request["steps"])
            elif op == "ppo":
                answer = ppo_throughput(request["algo"], request["sims"], request["updates"], request["n_steps"])
            else:
                raise ValueError(f"unknown request {op!r}")
        except Exception as exc:  # reported to the parent, which shows it in the table
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        answers.write(json.dumps(answer) + "\n")
        answers.flush()


# ================================================================================================
# Parent side: starts the workers, alternates their bursts, prints the tables.
# ================================================================================================
class WorkerError(RuntimeError):
    pass


class Worker:
    """One implementation's worker process."""

    def __init__(self, name: str, python: str, pythonpath: str, kind: str):
        self.name, self.path = name, pythonpath
        self._stderr = tempfile.TemporaryFile(mode="w+")
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [pythonpath, os.environ.get("PYTHONPATH")])),
                   MPLBACKEND="Agg", PYTHONWARNINGS="ignore")
        self._proc = subprocess.Popen([python, str(Path(__file__).resolve()), "--worker", kind],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr,
                                      text=True, env=env, cwd=pythonpath or None)
        self.info = self.call(op="info")

    def call(self, **request) -> dict:
        try:
            self._proc.stdin.write(json.dumps(request) + "\n")
            self._proc.stdin.flush()
            line = self._proc.stdout.readline()
        except (BrokenPipeError, OSError):
            line = ""
        if not line:
            self._stderr.seek(0)
            last = [line for line in self._stderr.read().splitlines() if line.strip()][-1:] or ["no message"]
            raise WorkerError(f"the {self.name} worker stopped: {last[0].strip()}")
        answer = json.loads(line)
        if "error" in answer:
            raise WorkerError(answer["error"])
        return answer

    def close(self):
        if self._proc.poll() is None:
            try:
                self._proc.stdin.write(json.dumps({"op": "quit"}) + "\n")
                self._proc.stdin.close()
            except OSError:
                pass
            try:
                self._proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self._proc.kill()
        self._stderr.close()


def _git_commit(path: Path) -> str:
    try:
        out = subprocess.run(["git", "-C", str(path), "describe", "--always", "--dirty", "--abbrev=7"],
                             capture_output=True, text=True, timeout=10)
        return out.stdout.strip() or "?"
    except (OSError, subprocess.SubprocessError):
        return "?"


def measure(workers: dict[str, Worker], cases: list[Case], sizes: Sizes, configs_dir: Path, log) -> dict:
    """Median rate of every (case, implementation), and paired ratios, from alternating bursts."""
    active: dict[str, list[str]] = {}
    errors: dict[str, dict[str, str]] = {}
    for case in cases:
        active[case.id] = []
        for name, w in workers.items():
            if name == REFERENCE and case.key not in ("gym", "reset"):
                continue
            try:
                w.call(op="setup", key=case.key, n=case.n, batch=case.batch, burst_s=sizes.burst_s,
                       configs_dir=str(configs_dir))
                active[case.id].append(name)
            except WorkerError as exc:
                errors.setdefault(case.id, {})[name] = str(exc)
                log(f"  {name}: {case.id} not measured: {exc}")
        log(f"  set up {case.id}")
    rates: dict[str, dict[str, list[float]]] = {c.id: {name: [] for name in active[c.id]} for c in cases}
    cpu_rates: dict[str, dict[str, list[float]]] = {c.id: {name: [] for name in active[c.id]} for c in cases}
    for r in range(sizes.rounds):
        for case in cases:
            names = active[case.id] if r % 2 == 0 else active[case.id][::-1]
            for name in names:
                burst = workers[name].call(op="burst", case=case.id)
                rates[case.id][name].append(burst["rate"])
                cpu_rates[case.id][name].append(burst["cpu_rate"])
        log(f"  round {r + 1}/{sizes.rounds}")
    episodes = {name: w.call(op="episodes") for name, w in workers.items()}
    return {"rates": rates, "cpu_rates": cpu_rates, "errors": errors, "episodes": episodes}


def paired_ratio(a: list[float], b: list[float]) -> float | None:
    """Median over rounds of a[r] / b[r] (None when either is missing)."""
    if not a or not b:
        return None
    return statistics.median(x / y for x, y in zip(a, b))


def summarise(raw: dict, cases: list[Case], names: list[str]) -> dict:
    rates = raw["rates"]
    rows = []
    for case in cases:
        row = {"case": case.id, "key": case.key, "n": case.n, "B": case.batch, "path": LABELS[case.key],
               "steps_per_s": {}, "steps_per_cpu_s": {}, "x_ours": {}, "errors": raw["errors"].get(case.id, {})}
        for name in names:
            if rates[case.id].get(name):
                row["steps_per_s"][name] = statistics.median(rates[case.id][name])
                row["steps_per_cpu_s"][name] = statistics.median(raw["cpu_rates"][case.id][name])
                if name != OURS:
                    row["x_ours"][name] = paired_ratio(rates[case.id].get(OURS, []), rates[case.id][name])
        rows.append(row)
    # PettingZoo step time ÷ centralised step time, per implementation (bursts of the same round)
    pz_vs_gym = {}
    for n in CONFIGS:
        gym, pz = rates[Case("gym", n, 1).id], rates[Case("pettingzoo", n, 1).id]
        pz_vs_gym[n] = {name: paired_ratio(gym.get(name, []), pz.get(name, [])) for name in names
                        if gym.get(name) and pz.get(name)}
    episode_length = {}
    for name, per_case in raw["episodes"].items():
        for cid, e in per_case.items():
            if e["resets"]:
                episode_length.setdefault(cid, {})[name] = e["steps"] / e["resets"]
    return {"rows": rows, "pettingzoo_over_centralised": pz_vs_gym, "mean_episode_steps": episode_length}


def judge(summary: dict, other: str | None, smoke: bool) -> list[dict]:
    """The issue's targets on this run's numbers (``other``: the compared checkout's name)."""
    rows = {(r["key"], r["n"]): r for r in summary["rows"]}
    targets = []

    def add(target, measured, met):
        if smoke:
            status = "not judged (smoke sizes)"
        else:
            status = "not measured" if met is None else ("met" if met else "**missed**")
        targets.append({"target": target, "measured": measured, "status": status, "met": met})

    for n in CONFIGS:
        x = rows[("gym", n)]["x_ours"].get(REFERENCE)
        add(f"centralised env, B = 1, n = {n}: ≥ 3× the earlier implementation",
            "reference not run" if x is None else f"{x:.2f}×", None if x is None else x >= 3)
    for n in CONFIGS:
        x = summary["pettingzoo_over_centralised"][n].get(OURS)
        add(f"PettingZoo parallel_env step, B = 1, n = {n}: within 3× of the centralised step",
            "–" if x is None else f"{x:.2f}× the centralised step time", None if x is None else x <= 3)
    for key in ("vec", "vec_gymnasium"):  # one core: steps per CPU-second of all the step's threads
        row = rows[(key, 11)]
        rate = row["steps_per_cpu_s"].get(OURS)
        add(f"{LABELS[key].split(' (')[0]}, n = 11, B = 4096: ≥ 2M env steps per CPU-second (B = {row['B']} here)",
            "–" if rate is None else f"{rate / 1e6:.2f}M", None if rate is None else rate >= 2e6)
    for n in CONFIGS:
        x = rows[("vec_agents", n)]["x_ours"].get(other) if other else None
        add(f"ContainerAgentsVecEnv, n = {n}, B = 4096: not slower than the compared checkout (≥ 0.95×)",
            "no --compare-with" if x is None else f"{x:.2f}×", None if x is None else x >= 0.95)
    return targets


# ---- output ------------------------------------------------------------------------------------
def _rate(x: float | None) -> str:
    return "–" if x is None else f"{x:,.0f}"


def _ratio(x: float | None) -> str:
    return "–" if x is None else f"{x:.2f}×"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(r) + " |" for r in rows]


def _rate_table(rows: list[dict], others: list[str], unit: str, agents: bool) -> list[str]:
    """Ours (rate, µs per call[, agent steps/s]), then each other implementation's rate and ours ÷ it."""
    header = ["path", "n", "B", f"ours {unit}/s", "µs per call", f"ours {unit} per CPU-second"]
    header += ["ours agent steps/s"] if agents else []
    for name in others:
        header += [f"{name} {unit}/s", f"ours ÷ {name}"]
    body = []
    for r in rows:
        ours = r["steps_per_s"].get(OURS)
        us_per_call = "–" if ours is None else f"{1e6 * r['B'] / ours:,.1f}"
        cells = [r["path"], str(r["n"]), str(r["B"]), _rate(ours), us_per_call, _rate(r["steps_per_cpu_s"].get(OURS))]
        if agents:
            cells.append(_rate(ours * r["n"]) if ours is not None and r["key"] == "vec_agents" else "–")
        for name in others:
            if name in r["errors"]:
                cells += ["error", "–"]
            else:
                cells += [_rate(r["steps_per_s"].get(name)), _ratio(r["x_ours"].get(name))]
        body.append(cells)
    return _table(header, body)


def markdown(result: dict) -> str:
    meta, s = result["meta"], result["summary"]
    others = [name for name in result["implementations"] if name != OURS]
    lines = [f"# Throughput ({'smoke' if meta['smoke'] else 'full'} run)", "",
             f"{meta['date']} · {meta['cpu']} · {meta['cpus']} CPUs · load average before {meta['load_before']}, "
             f"after {meta['load_after']} · {meta['duration_s']:.0f} s", ""]
    lines += [f"- **{name}**: {impl['description']}" for name, impl in result["implementations"].items()]
    lines += [f"- skipped: {msg}" for msg in result["skipped"]]
    lines += [f"- {name} could not run {r['case']}: {msg}" for r in s["rows"] for name, msg in r["errors"].items()]

    lines += ["", "## B = 1: centralised env, reset, PettingZoo parallel_env", ""]
    lines += _rate_table([r for r in s["rows"] if r["B"] == 1], others, "steps", agents=False)
    pz = s["pettingzoo_over_centralised"]
    lines += ["", "PettingZoo parallel_env step time ÷ centralised step time: " + "; ".join(
        f"n = {n}: " + ", ".join(f"{name} {_ratio(x)}" for name, x in pz[n].items()) for n in pz) + "."]
    if s["mean_episode_steps"]:
        lines += ["", "Mean episode length under these actions (steps): " + "; ".join(
            f"{cid}: " + ", ".join(f"{name} {v:,.0f}" for name, v in per.items())
            for cid, per in s["mean_episode_steps"].items()) + "."]

    lines += ["", f"## Vectorised envs, B = {result['sizes']['vec_batch']}", ""]
    lines += _rate_table([r for r in s["rows"] if r["B"] != 1], [x for x in others if x != REFERENCE],
                         "env steps", agents=True)
    threaded = [f"{name} from B = {impl['parallel_min_batch']}" for name, impl in result["implementations"].items()
                if impl.get("parallel_min_batch")]
    if threaded:
        lines += ["", f"The step of a large batch runs in {meta['cpus']} threads ({', '.join(threaded)}): on an "
                  f"idle machine its wall-clock rate is at most {meta['cpus']} × the rate per CPU-second."]
    if result.get("profile"):
        parts = list(result["profile"][0]["parts_us"])
        lines += ["", "## Where the time goes at B = 1 (ours; µs per step)", ""]
        lines += _table(["path", "n", "untimed", "with timers"] + parts,
                        [[LABELS[p["path"]], str(p["n"]), f"{p['untimed_us']:.1f}", f"{p['timed_us']:.1f}"]
                         + [f"{p['parts_us'][k]:.1f}" for k in parts] for p in result["profile"]])
        lines += ["", "kernel: the call of the compiled step (numba's unboxing of its arguments included); core around "
                  "the kernel: the rest of `dynamics.step_checked` (argument tuples; the simulator gives it its output "
                  "arrays); simulator bookkeeping: the rest of "
                  "`PlantSimulator.step`; resets: per step, amortised. The timers add the difference between the "
                  "two totals."]
    if result.get("ppo"):
        lines += ["", f"## SB3 PPO training ({PPO_CONFIG}, ours, package settings, torch threads = 1)", ""]
        lines += _table(["algorithm", "env slots", "samples/s", "env share of wall time", "projected 2M samples (min)"],
                        [[p["algo"], str(p["slots"]), _rate(p["samples_per_s"]), f"{100 * p['env_share']:.1f} %",
                          f"{p['projected_2M_min']:.1f}"] for p in result["ppo"]])
    lines += ["", "## Targets", ""]
    lines += _table(["target", "this run", "status"],
                    [[t["target"], t["measured"], t["status"]] for t in result["targets"]])
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true", help="tiny sizes (seconds); checks the tables, not speed")
    parser.add_argument("--json", type=Path, help="also write every number to this JSON file")
    parser.add_argument("--reference-python", default=os.environ.get(REFERENCE_ENV_VAR),
                        help=f"Python of a venv with numpy, matplotlib and gym==0.26.2 (default: ${REFERENCE_ENV_VAR});"
                             " without it the earlier implementation is not measured")
    parser.add_argument("--reference-impl", type=Path, default=SHARED / "reference-impl",
                        help="the earlier implementation's folder, its configs beside it in reference-configs/ "
                             "(default: ../shared/reference-impl)")
    parser.add_argument("--compare-with", type=Path, metavar="PATH",
                        help="another checkout of this package, measured beside ours (PYTHONPATH=PATH)")
    parser.add_argument("--compare-label", default="before", help="its name in the tables (default: before)")
    parser.add_argument("--skip-ppo", action="store_true", help="no PPO measurement")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    parser.add_argument("--worker", choices=("package", "reference"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        worker_main(args.worker)
        return {}
    if args.compare_label in (OURS, REFERENCE):
        parser.error(f"--compare-label: {args.compare_label!r} is taken")
    sizes = SMOKE if args.smoke else FULL

    def log(msg):
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    started = time.perf_counter()
    meta = {"date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"), "cpu": _cpu_name(),
            "cpus": os.cpu_count(), "load_before": _load(), "smoke": args.smoke}
    other = args.compare_label if args.compare_with else None
    reference_impl = args.reference_impl.resolve()
    configs_dir = reference_impl.parent / "reference-configs"
    workers: dict[str, Worker] = {}
    skipped: list[str] = []
    try:
        workers[OURS] = Worker(OURS, sys.executable, str(REPO), "package")
        if other:
            workers[other] = Worker(other, sys.executable, str(args.compare_with.resolve()), "package")
        if not args.reference_python:
            skipped.append(f"the earlier implementation: no --reference-python and no ${REFERENCE_ENV_VAR} (make "
                           "a venv with `python -m venv REFVENV && REFVENV/bin/pip install numpy matplotlib "
                           "gym==0.26.2`)")
        elif not (reference_impl / "containergym" / "env.py").is_file() or not configs_dir.is_dir():
            skipped.append(f"the earlier implementation: not found at {reference_impl} "
                           f"(with its configs at {configs_dir})")
        else:
            try:
                workers[REFERENCE] = Worker(REFERENCE, args.reference_python, str(reference_impl), "reference")
            except (WorkerError, OSError) as exc:
                skipped.append(f"the earlier implementation: its worker did not start ({exc})")
        for msg in skipped:
            log(f"skipped {msg}")
        impls = {name: _describe(name, w) for name, w in workers.items()}
        names = list(workers)
        cases = cases_for(sizes)
        log("environment throughput ...")
        raw = measure(workers, cases, sizes, configs_dir, log)
        result = {"meta": meta, "sizes": sizes.__dict__, "implementations": impls, "skipped": skipped,
                  "summary": summarise(raw, cases, names), "raw": raw}
        log("profile at B = 1 ...")
        result["profile"] = [workers[OURS].call(op="profile", key=key, n=n, steps=sizes.profile_steps)
                             for key in ("gym", "pettingzoo") for n in CONFIGS]
        if not args.skip_ppo:
            log("PPO ...")
            result["ppo"] = [workers[OURS].call(op="ppo", algo=algo, sims=sizes.ppo_sims, updates=sizes.ppo_updates,
                                                n_steps=sizes.ppo_n_steps) for algo in ("ppo", "shared_ppo")]
    finally:
        for w in workers.values():
            w.close()
    result["targets"] = judge(result["summary"], other, args.smoke)
    meta["load_after"] = _load()
    meta["duration_s"] = time.perf_counter() - started
    print(markdown(result), end="")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2, ensure_ascii=False))
    return result


def _describe(name: str, worker: Worker) -> dict:
    info = dict(worker.info, path=worker.path)
    if name != REFERENCE:
        info["commit"] = _git_commit(Path(worker.path))
    versions = ", ".join(f"{k} {info[k]}" for k in ("python", "numpy", "numba", "gym") if k in info)
    info["description"] = (f"`{info['module']}`" + (f" @ {info['commit']}" if "commit" in info else "")
                           + f" ({versions})")
    return info


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return f"{platform.machine()} {platform.processor() or platform.system()}"


if __name__ == "__main__":
    main()
