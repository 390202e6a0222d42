"""The default main job (``./run main`` = ``containergym-marl compare``): the shipped policies of a
published runs folder evaluated, never trained, the folder only read; training one option away."""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")
pytest.importorskip("stable_baselines3")

from containergym_marl.cli import build_parser, main  # noqa: E402
from containergym_marl.orchestration import (  # noqa: E402
    PAPER_METHODS,
    PAPER_ROWS,
    QUICK_TIMESTEPS,
    SHIPPED,
    CompareArgs,
    compare,
)
from containergym_marl.orchestration.compare_args import args_from_namespace  # noqa: E402
from containergym_marl.orchestration.plan import evaluation_fingerprint  # noqa: E402
from containergym_marl.orchestration.shipped import shipped_plan  # noqa: E402
from containergym_marl.evaluation import EvalProtocol  # noqa: E402
from containergym_marl.methods import METHODS  # noqa: E402
from containergym_marl.evaluation.run_policies import evaluate_run  # noqa: E402
from containergym_marl.manifest import write_manifest  # noqa: E402
from containergym_marl.rundir import model_file  # noqa: E402
from containergym_marl.training import TrainArgs, train  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CONFIG = "n5_m2_dt120"
EPISODES = 2  # the test protocol: 2 episodes (the paper's: 15)


def _snapshot(folder: Path) -> dict[str, tuple[str, int]]:
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def shipped(tmp_path_factory) -> Path:
    """A published folder as containergym-marl publish writes it: PPO seeds 1-3 finished (published
    evaluations of seeds 1 and 2 under the test protocol, none of seed 3), seed 4 published with a
    checkpoint only (still training), seed 5 finished without a best model, and a run named
    shared_ppo that was trained as PPO."""
    folder = tmp_path_factory.mktemp("published") / "paper_rows"
    runs = folder / "runs"
    protocol = EvalProtocol(episodes=EPISODES)
    args = CompareArgs(episodes=EPISODES)
    for seed in (1, 2, 3):
        run = train(TrainArgs(algo="ppo", config=CONFIG, seed=seed, timesteps=1024, n_envs=1, checkpoint_every=512,
                              out=str(runs / f"ppo_{CONFIG}_s{seed}"), progress_bar=False,
                              hyperparams={"n_steps": 128, "batch_size": 64},
                              overrides={"episode_length_steps": 40}))  # training episodes end: a best model
        shutil.rmtree(run / "checkpoints")  # containergym-marl publish ships a finished run without them
        shutil.rmtree(run / "tb", ignore_errors=True)
        if seed == 3:
            continue
        result = evaluate_run(run, protocol=protocol, write=False)
        data = json.loads(result.to_json())
        sha = hashlib.sha256((run / "best_model.zip").read_bytes()).hexdigest()
        data["compare"] = evaluation_fingerprint(args, CONFIG, METHODS["ppo"], run.name, sha, timesteps=1024)
        path = folder / "evaluations" / CONFIG / f"ppo_s{seed}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=2) + "\n")
    interrupted = runs / f"ppo_{CONFIG}_s4"
    (interrupted / "checkpoints").mkdir(parents=True)
    shutil.copyfile(runs / f"ppo_{CONFIG}_s1" / "args.json", interrupted / "args.json")
    shutil.copyfile(runs / f"ppo_{CONFIG}_s1" / "best_model.zip", interrupted / "checkpoints" / "ckpt_512_steps.zip")
    shutil.copytree(runs / f"ppo_{CONFIG}_s1", runs / f"shared_ppo_{CONFIG}_s1")
    shutil.copytree(runs / f"ppo_{CONFIG}_s1", runs / f"ppo_{CONFIG}_s5")
    (runs / f"ppo_{CONFIG}_s5" / "best_model.zip").unlink()
    write_manifest(folder)  # as containergym-marl publish does: the shipped model files' sha256
    return folder


def test_the_main_job_refuses_a_shipped_model_changed_after_publication(shipped, tmp_path):
    """A model whose bytes differ from the manifest (a tampered or corrupted file) is never
    evaluated: compare stops before any work, naming the file."""
    from containergym_marl.manifest import ManifestError

    copy = tmp_path / "paper_rows"
    shutil.copytree(shipped, copy)
    model = copy / "runs" / f"ppo_{CONFIG}_s2" / "best_model.zip"
    model.write_bytes(model.read_bytes()[:-1] + b"x")
    args = CompareArgs(configs=[CONFIG], methods=["ppo"], shipped=str(copy), episodes=EPISODES,
                       out=str(tmp_path / "cmp"), num_cpus=1, bootstrap_reps=200)
    with pytest.raises(ManifestError, match=f"ppo_{CONFIG}_s2/best_model.zip: its sha256 differs"):
        compare(args, stream=io.StringIO())
    assert not (tmp_path / "cmp" / "evaluations").exists()


def _published_means(folder: Path) -> dict[int, float]:
    means = {}
    for seed in (1, 2):
        data = json.loads((folder / "evaluations" / CONFIG / f"ppo_s{seed}.json").read_text())
        means[seed] = float(np.mean([e["cumulative_reward"] for e in data["episodes"]]))
    return means


@pytest.mark.slow  # starts a local Ray instance and evaluates every shipped policy, ~50 s
def test_the_main_job_evaluates_the_shipped_policies_and_trains_nothing(shipped, tmp_path):
    before = _snapshot(shipped)
    means = _published_means(shipped)
    best = max(means, key=lambda s: (means[s], -s))
    other = 3 - best
    out = tmp_path / "cmp"
    args = CompareArgs(configs=[CONFIG, "n5_m5_dt120"],
                       methods=["rule_based", "rule_based_agents", "ppo", "shared_ppo"], shipped=str(shipped),
                       episodes=EPISODES, out=str(out), num_cpus=2, bootstrap_reps=200)
    stream = io.StringIO()
    report = compare(args, stream=stream)
    printed = stream.getvalue()

    # What it says before it starts: what is shipped, what is skipped, which rows have nothing yet.
    assert f"the shipped policies of {shipped}/" in printed and "nothing is trained" in printed
    assert f"shipped policies on {CONFIG}: ppo (seeds 1, 2, 3; best s{best})" in printed
    assert ("still training (published with a checkpoint, no final model yet): "
            f"ppo_{CONFIG}_s4 (512 of 1,024 samples)") in printed
    assert f"shared_ppo_{CONFIG}_s1 was trained as ppo, not as shared_ppo" in printed
    assert f"ppo_{CONFIG}_s5 has no best model (no training episode finished)" in printed
    assert "no shipped policies yet on n5_m5_dt120 (rule_based and rule_based_agents only)" in printed

    # Evaluated now: the rule-based controllers, the best published seed, the seed without a published
    # evaluation; the other seed's published evaluation is copied into --out.
    sweep = report["sweep"]
    assert sweep["trained"] == [] and sweep["ray"].startswith("local Ray instance")
    assert sorted(sweep["evaluated"]) == sorted(
        [f"{c}/{m}" for c in (CONFIG, "n5_m5_dt120") for m in ("rule_based", "rule_based_agents")]
        + [f"{CONFIG}/ppo_s{best}", f"{CONFIG}/ppo_s3"])
    copied = json.loads((out / "evaluations" / CONFIG / f"ppo_s{other}.json").read_text())
    assert copied["copied_from"] == str(shipped / "evaluations" / CONFIG / f"ppo_s{other}.json")
    assert sweep["shipped"]["reproduced"] == [f"{CONFIG}/ppo_s{best}"] and sweep["shipped"]["differ"] == []
    assert sweep["shipped"]["without_shipped_policies"] == ["n5_m5_dt120"]

    # The table: every finished seed, the best one as the published evaluations rank it.
    rows = {(r["config"], r["method"]): r for r in report["rows"]}
    assert set(rows) == {(c, m) for c in (CONFIG, "n5_m5_dt120") for m in ("rule_based", "rule_based_agents")} | {
        (CONFIG, "ppo")}
    ppo = rows[(CONFIG, "ppo")]
    assert ppo["seeds"] == 3 and ppo["samples"] == 1024
    assert report["seed_means"][f"{CONFIG}/ppo"][best - 1] == pytest.approx(means[best])
    assert max(report["seed_means"][f"{CONFIG}/ppo"][:2]) == pytest.approx(means[best])
    # ... printed as a readable table, then the files it wrote, by name.
    table_lines = [line for line in printed.splitlines() if " ppo " in line and "centralised" in line]
    assert table_lines and f"{ppo['best_mean']:.2f} ± {ppo['best_std']:.2f}" in table_lines[0]
    assert any(line.startswith(" n5_m5_dt120 ") and "rule_based" in line for line in printed.splitlines())
    assert "paper PPO" in printed and "P(rule_based_agents > rule_based)" in printed
    assert "The 1 shipped policy evaluated now returns what its published evaluation says" in printed
    assert "No shipped policies yet on n5_m5_dt120" in printed
    tail = printed[printed.index(f"files ({out}/):"):]
    for expected in (f"table: {out / 'table.md'} (also table.csv, table.json)", f"evaluations: {out / 'evaluations'}/",
                     f"figures: {out / 'figures'}/", f"what this call did: {out / 'sweep.json'}",
                     f"shipped runs (only read): {shipped / 'runs'}/", "nothing trained"):
        assert expected in tail, expected
    assert all(line == line.rstrip() for line in printed.splitlines())  # no blanks padding the table
    for name in ("table.md", "table.csv", "table.json", "sweep.json"):
        assert (out / name).is_file()
    assert f"| {CONFIG} | ppo | centralised | 3 |" in (out / "table.md").read_text()
    figures = {p.name for p in (out / "figures").iterdir()}
    # the headline figures by default: the first row's ECDFs and an episode of each method, nothing else
    stems = {name.rsplit(".", 1)[0] for name in figures}
    assert stems == {f"{CONFIG}_{kind}" for kind in ("reward_ecdf", "emptying_volume_ecdfs", "episode_ppo",
                                                      "episode_rule_based", "episode_rule_based_agents")}
    assert f"figures: {CONFIG}: 5 drawn in" in printed

    # The published folder is only read: nothing trained, written or removed there.
    assert _snapshot(shipped) == before

    # Again: every evaluation is reused from --out; without figures no Ray is started.
    again = compare(CompareArgs(**{**args.__dict__, "figures": "none"}), stream=io.StringIO())
    assert again["sweep"]["evaluated"] == [] and again["sweep"]["ray"] is None
    assert json.dumps(again["rows"]) == json.dumps(report["rows"])
    assert _snapshot(shipped) == before


def test_training_needs_train_and_the_sweep_script_still_trains(tmp_path, capsys):
    parse = build_parser().parse_args

    default = args_from_namespace(parse(["compare"]))
    assert default.shipped == SHIPPED and default.timesteps is None and default.runs is None
    assert default.configs == list(PAPER_ROWS) and default.methods == list(PAPER_METHODS)

    quick = args_from_namespace(parse(["compare", "--train"]))
    assert quick.shipped is None and quick.timesteps == QUICK_TIMESTEPS and quick.configs == ["n5_m2_dt120"]
    assert quick.seeds == [1, 2, 3] and quick.methods == ["rule_based", "rule_based_agents", "ppo", "shared_ppo"]
    for argv, timesteps in ((["--timesteps", "2e6"], 2_000_000), (["--seeds", "4"], QUICK_TIMESTEPS),
                            (["--runs", "r"], QUICK_TIMESTEPS), (["--hp", "n_steps=64"], QUICK_TIMESTEPS)):
        trained = args_from_namespace(parse(["compare", "--train", *argv]))
        assert trained.shipped is None and trained.timesteps == timesteps, argv
        with pytest.raises(ValueError, match=f"{argv[0]}: training options; add --train"):
            args_from_namespace(parse(["compare", *argv]))  # never a training run without --train

    # baselines/sweep_paper_rows.sh's command line, as it is: training at the paper's budgets.
    script = (ROOT / "baselines" / "sweep_paper_rows.sh").read_text()
    line = script[script.index("compare --train \\") + len("compare "):].replace("\\\n", " ").split('"$@"')[0]
    argv = [w.strip('"') for w in line.split()]
    argv = [{"$RUNS": "runs/paper", "$OUT": "results/compare_paper"}.get(w, w) for w in argv]
    sweep = args_from_namespace(parse(["compare", *argv]))
    assert sweep.shipped is None and sweep.timesteps is None and sweep.seeds == [1, 2, 3]
    assert len(sweep.configs) == 9 and set(sweep.configs) == set(PAPER_ROWS) and sweep.runs == "runs/paper"

    with pytest.raises(ValueError, match="--shipped evaluates published runs and trains nothing; drop --train"):
        args_from_namespace(parse(["compare", "--shipped", "x", "--train"]))
    assert main(["compare", "--shipped", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "no folder" in err and "--train" in err and not (tmp_path / "o").exists()

    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for expected in ("With no arguments it trains nothing", "--train", f"default: {SHIPPED}",
                     "default with --train: 30000", "n16_m2_dt120, for the shipped policies"):
        assert expected in text, expected


def test_the_repository_s_shipped_folder_is_planned_from_its_files(tmp_path):
    """The default main job's plan on results/paper_rows as committed: every paper row gets its
    rule-based evaluations; a row is named as missing exactly when no finished run is shipped for it."""
    args = CompareArgs(configs=list(PAPER_ROWS), methods=list(PAPER_METHODS), shipped=str(ROOT / SHIPPED),
                       out=str(tmp_path / "cmp"))
    plan = shipped_plan(args, tmp_path / "cmp")
    keys = {(spec.config, spec.key) for spec, _ in plan.to_evaluate} | set(plan.evaluations)
    assert {(c, m) for c in PAPER_ROWS for m in ("rule_based", "rule_based_agents")} <= keys
    finished = {p.name for p in (ROOT / SHIPPED / "runs").glob("*") if (p / model_file(p, "final")).is_file()}
    assert plan.finished <= finished
    for config in PAPER_ROWS:
        assert (config in plan.shipped.missing) == (config not in plan.shipped.learned)
