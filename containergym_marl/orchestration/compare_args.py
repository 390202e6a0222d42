"""What a comparison is asked to do: :class:`CompareArgs`, whose fields are also the options of
``containergym-marl compare`` (:mod:`containergym_marl.options`), and their checks."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

from containergym_marl.algorithms import paper_budget
from containergym_marl.config import list_configs, load_config
from containergym_marl.evaluation.protocol import PROTOCOLS, EvalProtocol
from containergym_marl.methods import COMPARABLE, METHODS
from containergym_marl.options import add_options, flag_of, key_values, option, option_fields, values

#: Which figures compare draws: none; the headline figures (:data:`HEADLINE_ROW`, or the first row
#: compared: the reward and emptying-volume ECDFs and one episode of each method's best policy); or
#: all of them for every row (also PU timelines and the reward functions).
FIGURE_SETS = ("none", "headline", "all")
#: The row whose figures are the headline ones (the contention row: 11 containers, 2 PUs).
HEADLINE_ROW = "n11_m2_dt120"
#: The samples per run of ``compare --train`` (a look in minutes, not a result).
QUICK_TIMESTEPS = 30_000
#: The rows of the comparison the repository publishes (baselines/sweep_paper_rows.sh): the paper's
#: eight configurations and the 16-container plant, in the table's order.
PAPER_ROWS = ("n5_m2_dt60", "n5_m2_dt120", "n5_m5_dt60", "n5_m5_dt120", "n11_m2_dt60", "n11_m2_dt120",
              "n11_m11_dt60", "n11_m11_dt120", "n16_m2_dt120")
#: Its methods: the rule-based controllers and the paper's PPO baselines as the package trains them
#: (the native trainer, 15 seeds a row): centralised PPO and shared PPO with individual and team
#: rewards. Stable-Baselines3's runs of the same methods at the paper's settings (``ppo``,
#: ``shared_ppo``, ``shared_ppo_team``) are shipped too: ``--methods`` names them.
PAPER_METHODS = ("rule_based", "rule_based_agents", "fast_ppo", "fast_shared_ppo", "fast_shared_ppo_team")
#: Where the repository publishes the comparison's runs and evaluations (containergym-marl publish).
SHIPPED = "results/paper_rows"
#: What ``--timesteps paper`` gives on the command line (CompareArgs.timesteps None: the paper's budget).
PAPER_BUDGET = "paper"

#: The help sections of ``compare``; the options of TRAINING need ``--train``.
WHAT, TRAINING, EXECUTION = "what to compare", "training", "execution"
SECTIONS = {
    WHAT: "without --train, compare evaluates the shipped policies and trains nothing",
    TRAINING: "--train trains (or reuses the finished runs of --runs) instead of evaluating the shipped\n"
              "policies; the other options here need it. compare says how long it will take before it starts",
    EXECUTION: None,
}


def _timesteps(text: str) -> int | str:
    if text == PAPER_BUDGET:
        return PAPER_BUDGET
    try:
        value = int(float(text)) if "e" in text.lower() else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of samples or 'paper', got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number of samples, got {value}")
    return value


def _budget_or_paper(value: int | str, flag: str) -> int | None:
    return None if value == PAPER_BUDGET else value


@dataclass
class CompareArgs:
    """A comparison of methods on plant configurations (see :mod:`~containergym_marl.orchestration.compare`).

    ``timesteps`` None: the paper's budget of each config (2M samples for n = 5, 5M for n >= 11).
    ``n_envs`` None: each algorithm's default. ``address`` None: ``$RAY_ADDRESS`` if set, else a
    local Ray instance with ``num_cpus`` CPUs (None: all cores).

    ``shipped`` set (a folder that containergym-marl publish wrote, e.g. :data:`SHIPPED`): train
    nothing and evaluate the finished runs published there instead; the options of the training
    section are then unused (each run was trained as its args.json says), and ``timesteps`` and
    ``runs`` must stay None.
    """

    configs: list[str] = option(
        default_factory=lambda: ["n5_m2_dt120"], nargs="+", metavar="CONFIG", group=WHAT, show_default=False,
        help=f"plant configurations: built-in ({', '.join(list_configs())}) or paths (default: the paper rows, "
             f"{' '.join(PAPER_ROWS)}, for the shipped policies; n5_m2_dt120 with --train)")
    methods: list[str] = option(
        default_factory=lambda: ["rule_based", "rule_based_agents", "ppo", "shared_ppo"], nargs="+",
        choices=COMPARABLE, metavar="METHOD", group=WHAT, show_default=False,
        help=f"methods to compare, from: {', '.join(COMPARABLE)} (default: {' '.join(PAPER_METHODS)} for the "
             f"shipped policies; rule_based rule_based_agents ppo shared_ppo with --train)")
    protocol: str = option("paper", choices=("paper", "validation", "fresh"), group=WHAT,
                           help="the episodes of every evaluation (δ = 120 s, T = 600): paper, the test seeds "
                                "10000+ (15 episodes); validation, seeds 20000+ for choosing settings (30); fresh, "
                                "seeds 30000+ for reporting only (200)")
    episodes: int | None = option(None, type=int, group=WHAT,
                                  help="episodes per evaluation (default: the protocol's)")
    out: str = option("results/compare", group=WHAT, help="tables, evaluations and figures")
    shipped: str | None = option(
        None, metavar="DIR", group=WHAT,
        help=f"the folder of published runs whose policies are evaluated, only read (default: {SHIPPED}, the "
             f"repository's; containergym-marl publish writes such folders)")
    timesteps: int | None = option(
        None, type=_timesteps, convert=_budget_or_paper, metavar="N|paper", group=TRAINING,
        help=f"samples per training run; 'paper' = the paper's budget of each config (2M for n=5, 5M for n>=11) "
             f"(default with --train: {QUICK_TIMESTEPS})")
    seeds: list[int] = option(default_factory=lambda: [1, 2, 3], type=int, nargs="+", metavar="SEED",
                              group=TRAINING, help="training seeds of every learned method, distinct")
    runs: str | None = option(None, group=TRAINING,
                              help="run directories (default <out>/runs); on a cluster, a path every node reaches")
    n_envs: int | None = option(None, type=int, group=TRAINING,
                                help="parallel simulations per run (default: the algorithm's)")
    checkpoint_every: int = option(200_000, type=int, group=TRAINING,
                                   help="samples between checkpoints, what an interruption can lose")
    curves: bool = option(False, action="store_true", group=TRAINING,
                          help="after training, evaluate each run's checkpoints at every tenth of its budget on "
                               "the validation episodes into RUN/curve.json (its sample-efficiency curve)")
    hyperparams: dict = option(default_factory=dict, flag="--hp", nargs="*", metavar="KEY=VALUE", group=TRAINING,
                               convert=key_values, help="further settings of every learned method's algorithm")
    address: str | None = option(None, group=EXECUTION,
                                 help="Ray cluster to run on (default: $RAY_ADDRESS, else a new local Ray instance)")
    num_cpus: int | None = option(None, type=int, group=EXECUTION,
                                  help="CPUs of the local Ray instance, one training at a time each (default: "
                                       "all cores)")
    max_retries: int = option(3, type=int, group=EXECUTION,
                              help="Ray retries of a task whose worker dies (a retried training resumes)")
    bootstrap_reps: int = option(2000, type=int, group=EXECUTION,
                                 help="bootstrap replicates of every confidence interval")
    reevaluate: bool = option(False, action="store_true", group=EXECUTION,
                              help="evaluate again even where an evaluation of the same model, plant and "
                                   "protocol exists")
    figures: str = option("headline", choices=FIGURE_SETS, group=EXECUTION,
                          help=f"figures to draw: none, the headline ones ({HEADLINE_ROW}, or the first row: reward "
                               f"and emptying-volume ECDFs, an episode of each method) or all, for every row")

    def validate(self) -> None:
        """Refuse bad values before any work (a ValueError naming the field)."""
        if self.figures not in FIGURE_SETS:
            raise ValueError(f"figures: expected one of {FIGURE_SETS}, got {self.figures!r}")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise ValueError(f"methods: unknown method(s) {unknown}; choose from {list(COMPARABLE)}")
        by_script = [f"{m} (trained by {METHODS[m].algorithm.trainer_name})" for m in self.methods
                     if m not in COMPARABLE]
        if by_script:
            raise ValueError(f"methods: compare does not train {', '.join(by_script)}; choose from {list(COMPARABLE)}")
        for what in ("configs", "methods", "seeds"):
            items = getattr(self, what)
            repeated = sorted({v for v in items if items.count(v) > 1}, key=str)
            if repeated:
                raise ValueError(f"{what}: {', '.join(map(str, repeated))} given more than once")
        for c in self.configs:
            load_config(c)  # ConfigError for unknown names, before any work
        if self.shipped is not None:
            if self.timesteps is not None or self.runs is not None:
                raise ValueError("shipped: the shipped policies are evaluated as they were trained; "
                                 "timesteps and runs are for training (leave shipped unset to train)")
            if not Path(self.shipped).is_dir():
                raise FileNotFoundError(
                    f"shipped policies: no folder {self.shipped!r} (the repository publishes them in {SHIPPED}/; "
                    f"run from the repository's root, name the folder with --shipped, or train with --train)")
        elif any(METHODS[m].learned for m in self.methods) and not self.seeds:
            raise ValueError("seeds: at least one training seed is needed")
        if self.timesteps is not None and self.timesteps <= 0:
            raise ValueError(f"timesteps: expected a positive budget, got {self.timesteps}")
        if self.protocol not in PROTOCOLS:
            raise ValueError(f"protocol: unknown protocol {self.protocol!r}; choose one of {tuple(PROTOCOLS)}")
        if self.episodes is not None and (isinstance(self.episodes, bool) or not isinstance(self.episodes, int)
                                          or self.episodes <= 0):
            raise ValueError(f"episodes: expected at least one episode, got {self.episodes!r}")

    def eval_protocol(self) -> EvalProtocol:
        """The episodes every evaluation of the comparison runs: ``protocol``'s, ``episodes`` of them
        when given."""
        base = PROTOCOLS[self.protocol]
        return base if self.episodes is None else dataclasses.replace(base, episodes=int(self.episodes))

    def budget(self, config: str) -> int:
        """Samples per training run on ``config``: ``timesteps``, or the paper's budget."""
        if self.timesteps is not None:
            return int(self.timesteps)
        return paper_budget(load_config(config).n_containers)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``containergym-marl compare``: :class:`CompareArgs`' fields, ``--train`` and
    ``--no-figures``."""
    sections = {name: parser.add_argument_group(name, text) for name, text in SECTIONS.items()}
    sections[TRAINING].add_argument(
        "--train", action="store_true",
        help=f"train the learned methods: {QUICK_TIMESTEPS:,} samples per run unless --timesteps, a quick look in "
             f"minutes, far from a result (default: evaluate the shipped policies)")
    add_options(parser, CompareArgs, groups=sections)
    sections[EXECUTION].add_argument("--no-figures", dest="figures", action="store_const", const="none",
                                     default=argparse.SUPPRESS,
                                     help="the same as --figures none")


def args_from_namespace(ns: argparse.Namespace) -> CompareArgs:
    """CompareArgs of a parsed ``compare`` command line: the shipped policies, or training with
    ``--train`` (each unset option then keeps CompareArgs' default, and the budget is
    :data:`QUICK_TIMESTEPS`). A training option without ``--train`` is refused rather than taken as
    a wish to train."""
    given = values(CompareArgs, ns)
    training = [flag_of(f) for f in option_fields(CompareArgs)
                if f.metadata["option"]["group"] == TRAINING and f.name in given]
    if not ns.train:
        if training:
            raise ValueError(f"{', '.join(training)}: training options; add --train to train (without it compare "
                             f"evaluates the shipped policies and trains nothing)")
        return CompareArgs(**{"configs": list(PAPER_ROWS), "methods": list(PAPER_METHODS), "shipped": SHIPPED,
                              **given})
    if "shipped" in given:
        raise ValueError(f"--shipped evaluates published runs and trains nothing; drop "
                         f"{', '.join(['--train', *training])} or --shipped")
    return CompareArgs(**{"timesteps": QUICK_TIMESTEPS, **given})

