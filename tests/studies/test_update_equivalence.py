"""studies/update_equivalence.py: its autograd reference is autograd's update, and a smoke run reports."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow  # a study's smoke run, ~15 s
def test_update_equivalence_reference_is_the_autograd_update_and_the_smoke_run_reports(tmp_path):
    """studies/update_equivalence.py: its ``autograd`` variant's update reaches the weights of the
    trainer's compiled update from the same start (one update of four minibatches, to float
    rounding), and a smoke run trains both variants and writes the comparison."""
    sys.path.insert(0, str(REPO / "studies"))
    try:
        import update_equivalence
    finally:
        sys.path.remove(str(REPO / "studies"))
    import torch

    from containergym_marl.policies.actor_critic import ActorCritic
    from containergym_marl.training import fast_ppo
    from containergym_marl.training.fast_ppo import PPOArgs, update

    gen = torch.Generator().manual_seed(3)
    obs, actions = torch.randn(512, 19, generator=gen), torch.randint(0, 2, (512,), generator=gen)
    old_logp, adv, ret = torch.full((512,), -0.7), torch.randn(512, generator=gen), torch.randn(512, generator=gen)
    hp = PPOArgs(minibatch_size=128, n_epochs=1, learning_rate=1e-3)
    models = [ActorCritic("decentralised", 19, 2, generator=torch.Generator().manual_seed(1)) for _ in range(2)]
    start = [p.detach().clone() for p in models[0].net.parameters()]
    for model, fn, new_optimizer in zip(models, (update, update_equivalence.autograd_update),
                                        (fast_ppo._optimizer, update_equivalence.autograd_optimizer)):
        optimizer = new_optimizer(model, hp)
        fn(model, optimizer, hp, torch.Generator().manual_seed(0), obs, actions, old_logp, adv, ret)
    for a, b, s in zip(models[0].net.parameters(), models[1].net.parameters(), start):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
        assert not torch.equal(a, s)

    # a worker trains one run after another: each run sets its variant's update, whatever ran before
    assert update_equivalence.use_update("autograd") is update_equivalence.autograd_update is fast_ppo.update
    assert fast_ppo._optimizer is update_equivalence.autograd_optimizer
    assert update_equivalence.use_update("compiled") is update is fast_ppo.update
    assert fast_ppo._optimizer is update_equivalence.COMPILED[1]

    out = tmp_path / "eq"
    proc = subprocess.run([sys.executable, str(REPO / "studies" / "update_equivalence.py"), "--smoke",
                           "--workers", "1", "--out", str(out), "--hp", '{"minibatch_size": 64}'], capture_output=True, text=True, timeout=600,
                          check=True, cwd=tmp_path)
    report = json.loads((out / "equivalence.json").read_text())
    assert sorted((e["variant"], e["seed"]) for e in report["entries"]) == [
        ("autograd", 101), ("autograd", 102), ("compiled", 101), ("compiled", 102)]
    assert all(e["samples"] == 8192 and e["hyperparams"] == {"minibatch_size": 64} for e in report["entries"]) and "permutation test" in proc.stdout
