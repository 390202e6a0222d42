"""The native PPO's written-out gradients (training/ppo_gradients.py) against autograd: the networks'
outputs bit for bit and their gradients to float rounding, the same norm clip; the clipped loss's
gradients and diagnostics."""

from __future__ import annotations

import pytest
import torch

from containergym_marl.policies.actor_critic import MASKED_LOGIT, ActorCritic
from containergym_marl.training.ppo_gradients import FlatAdam, MLPGradients, ppo_loss_gradients


@pytest.mark.parametrize("view, obs_size, n_actions, hidden", [
    ("decentralised", 7, 2, (64, 64)),  # a container agent: a narrow first layer
    ("centralised", 33, 12, (64, 64)),
    ("decentralised", 5, 2, (16, 32, 8)),  # three hidden layers of different widths
])
def test_outputs_and_gradients_equal_autograds(view, obs_size, n_actions, hidden):
    gen = torch.Generator().manual_seed(4)
    model = ActorCritic(view, obs_size, n_actions, hidden, generator=gen)
    obs = torch.randn(300, obs_size, generator=gen)
    g_logits, g_values = torch.randn(300, n_actions, generator=gen), torch.randn(300, generator=gen)

    logits, values = model.logits(obs), model.value(obs)
    torch.autograd.backward([logits, values], [g_logits, g_values])
    expected = [p.grad.clone() for p in model.net.parameters()]

    nets = MLPGradients(model)
    got_logits, got_values = nets.forward(obs)
    assert torch.equal(got_logits, logits.detach()) and torch.equal(got_values, values.detach())
    nets.backward(g_logits, g_values)
    for (name, p), want in zip(model.net.named_parameters(), expected):
        torch.testing.assert_close(p.grad, want, rtol=1e-5, atol=1e-5, msg=name)
        assert p.grad.data_ptr() != want.data_ptr()
    # every gradient is a view of the one flat buffer that the clip scales
    assert sum(p.grad.numel() for p in model.net.parameters()) == nets.flat_grad.numel()
    norm = torch.linalg.vector_norm(torch.cat([w.flatten() for w in expected]))
    nets.clip_grad_norm_(0.5)
    for p, want in zip(model.net.parameters(), expected):
        torch.testing.assert_close(p.grad, want * (0.5 / (norm + 1e-6)), rtol=1e-5, atol=1e-6)
    before = nets.flat_grad.clone()
    nets.clip_grad_norm_(1e9)  # within the bound: unchanged
    assert torch.equal(nets.flat_grad, before)


@pytest.mark.parametrize("flat", [False, True])
def test_forward_follows_parameters_changed_in_place(flat):
    """The forward computes its hidden layers with doubled copies of their parameters: after the
    optimiser (or a load) changes the parameters in place, the next forward is the module's again, bit
    for bit; inside fixed_parameters() the copies made on entering serve every forward."""
    gen = torch.Generator().manual_seed(5)
    model = ActorCritic("decentralised", 9, 2, generator=gen)
    optimizer = FlatAdam(model.net.parameters(), lr=0.05, eps=1e-5) if flat else None
    nets = MLPGradients(model, optimizer)
    obs = torch.randn(40, 9, generator=gen)

    def same_as_module():
        logits, values = nets.forward(obs, keep=False)
        with torch.no_grad():
            return torch.equal(logits, model.logits(obs)) and torch.equal(values, model.value(obs))

    assert same_as_module()
    with nets.fixed_parameters():
        before = nets.forward(obs, keep=False)[0]
        assert torch.equal(nets.forward(obs, keep=False)[0], before)
    nets.forward(obs)
    nets.backward(torch.randn(40, 2, generator=gen), torch.randn(40, generator=gen))
    if flat:
        optimizer.step()  # writes the flat buffer, not the parameters themselves
    else:
        with torch.no_grad():
            for p in model.net.parameters():
                p.sub_(0.05 * p.grad)
    assert not torch.equal(nets.forward(obs, keep=False)[0], before)
    assert same_as_module()
    model.net.load_state_dict(ActorCritic("decentralised", 9, 2, generator=gen).net.state_dict())
    with nets.fixed_parameters():
        assert same_as_module()


def _autograd_loss(logits, values, actions, old_logp, adv, returns, clip, vf_coef, ent_coef, masks):
    """SB3's PPO loss through autograd (the trainer's loss before it was written out)."""
    if masks is not None:
        logits = logits.masked_fill(~masks, MASKED_LOGIT)
    log_probs = torch.log_softmax(logits, -1)
    log_ratio = log_probs.gather(-1, actions[:, None]).squeeze(-1) - old_logp
    ratio = log_ratio.exp()
    policy_loss = -torch.min(adv * ratio, adv * torch.clamp(ratio, 1 - clip, 1 + clip)).mean()
    entropy = -(log_probs.exp() * log_probs.clamp_min(torch.finfo(log_probs.dtype).min)).sum(-1).mean()
    return policy_loss + vf_coef * torch.nn.functional.mse_loss(returns, values) - ent_coef * entropy, entropy, ratio, log_ratio


@pytest.mark.parametrize("n_actions, masked, ent_coef", [(2, False, 0.0), (6, True, 0.01), (2, False, 0.05)])
def test_loss_gradients_equal_autograds(n_actions, masked, ent_coef):
    """Samples with ratios inside the clip range (ties of the two surrogates, as in every first epoch:
    r = 1), above and below it, positive and negative advantages; masked actions."""
    gen = torch.Generator().manual_seed(7)
    b, clip = 240, 0.2
    logits = torch.randn(b, n_actions, generator=gen) * 2
    values, returns = torch.randn(b, generator=gen), torch.randn(b, generator=gen)
    masks = torch.rand(b, n_actions, generator=gen) < 0.7 if masked else None
    if masks is not None:
        masks[:, 0] = True
    actions = torch.multinomial(torch.softmax(logits if masks is None else logits.masked_fill(~masks, MASKED_LOGIT), -1),
                                1, generator=gen).squeeze(-1)
    with torch.no_grad():
        current = torch.log_softmax(logits if masks is None else logits.masked_fill(~masks, MASKED_LOGIT), -1)
        current = current.gather(-1, actions[:, None]).squeeze(-1)
    # a third at ratio 1, a third within the range, a third well outside it (either side)
    shift = torch.cat([torch.zeros(b // 3), torch.empty(b // 3).uniform_(-0.1, 0.1, generator=gen),
                       torch.empty(b - 2 * (b // 3)).uniform_(-1.0, 1.0, generator=gen)])
    old_logp = current + shift
    adv = torch.randn(b, generator=gen)

    z, v = logits.clone().requires_grad_(), values.clone().requires_grad_()
    loss, entropy, ratio, log_ratio = _autograd_loss(z, v, actions, old_logp, adv, returns, clip, 0.5, ent_coef, masks)
    want_z, want_v = torch.autograd.grad(loss, (z, v))

    g_z, g_v, diagnostics = ppo_loss_gradients(logits, values, actions, old_logp, adv, returns, clip, 0.5, ent_coef, masks)
    torch.testing.assert_close(g_z, want_z, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(g_v, want_v, rtol=1e-6, atol=1e-8)
    assert (want_z.abs() > 1e-4).sum() > b // 2  # the comparison is of gradients that are there
    if masks is not None:
        assert torch.all(g_z[~masks] == 0)
    assert float(diagnostics["entropy"]) == pytest.approx(float(entropy.detach()), rel=1e-6)
    assert float(diagnostics["approx_kl"]) == pytest.approx(float(((ratio - 1) - log_ratio).mean().detach()), rel=1e-5)
    clipped = float(((ratio.detach() - 1).abs() > clip).float().mean())
    assert float(diagnostics["clip_fraction"]) == clipped and 0 < clipped < 1


def test_flat_adam_steps_as_torch_adam_and_reads_its_state():
    """Five steps of FlatAdam against torch.optim.Adam from the same start with the same gradients;
    then FlatAdam loaded from torch's state (a version-1 checkpoint) and from its own continues as
    torch's optimiser does. The parameters are views of the flat buffer throughout."""
    gen = torch.Generator().manual_seed(5)
    models = [ActorCritic("decentralised", 6, 2, (8, 8), generator=torch.Generator().manual_seed(2)) for _ in range(2)]
    ours = FlatAdam(models[0].net.parameters(), lr=1e-2, eps=1e-5)
    theirs = torch.optim.Adam(models[1].net.parameters(), lr=1e-2, eps=1e-5)
    grads = [[torch.randn(p.shape, generator=gen) for p in models[0].net.parameters()] for _ in range(8)]

    def step(model, optimizer, gs):
        for p, g in zip(model.net.parameters(), gs):
            p.grad.copy_(g) if isinstance(optimizer, FlatAdam) else setattr(p, "grad", g.clone())
        optimizer.step()

    for gs in grads[:5]:
        step(models[0], ours, gs)
        step(models[1], theirs, gs)
    for a, b in zip(models[0].net.parameters(), models[1].net.parameters()):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)
        assert a.data_ptr() != b.data_ptr()
    assert models[0].net.actor[0].weight.untyped_storage().data_ptr() == ours.flat_param.untyped_storage().data_ptr()

    resumed = ActorCritic.from_dict(models[1].to_dict(), "test")
    from_torch = FlatAdam(resumed.net.parameters(), lr=0.5, eps=1e-5)
    from_torch.load_state_dict(theirs.state_dict())
    assert (from_torch.steps, from_torch.param_groups[0]["lr"]) == (5, 1e-2)
    again = ActorCritic.from_dict(models[0].to_dict(), "test")
    from_own = FlatAdam(again.net.parameters(), lr=0.5, eps=1e-5)
    from_own.load_state_dict(ours.state_dict())
    for gs in grads[5:]:
        for model, optimizer in ((resumed, from_torch), (again, from_own), (models[1], theirs)):
            step(model, optimizer, gs)
    for a, b, c in zip(resumed.net.parameters(), again.net.parameters(), models[1].net.parameters()):
        torch.testing.assert_close(a, c, rtol=1e-6, atol=1e-7)
        torch.testing.assert_close(b, c, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match="moments"):
        FlatAdam(ActorCritic("decentralised", 6, 2, (4,)).net.parameters(), 1e-3, 1e-5).load_state_dict(ours.state_dict())


def test_behaviour_cloning_gradients_equal_autograds():
    """DAPG's term (dagger_dapg_agents' fine-tuning): weight × mean cross-entropy, through autograd."""
    from containergym_marl.training.fast_ppo import behaviour_cloning_gradients

    gen = torch.Generator().manual_seed(3)
    logits, labels = torch.randn(50, 2, generator=gen) * 3, torch.randint(2, (50,), generator=gen)
    z = logits.clone().requires_grad_()
    (want,) = torch.autograd.grad(0.7 * torch.nn.functional.cross_entropy(z, labels), z)
    torch.testing.assert_close(behaviour_cloning_gradients(logits, labels, 0.7), want, rtol=1e-6, atol=1e-8)


def test_one_update_with_the_behaviour_cloning_term_follows_the_summed_loss():
    """One PPO update (one epoch, one minibatch) with DAPG's term at weight 0.8: the gradient it steps
    on is autograd's of PPO's loss on the rollout plus 0.8 × the cross-entropy on the demonstrations it
    drew (the run's generator: the minibatch order, then the demonstrations), the value network's
    gradient PPO's alone. At weight 0 the update is PPO's, bit for bit, and draws nothing more."""
    from containergym_marl.training import fast_ppo

    gen = torch.Generator().manual_seed(11)
    model = ActorCritic("decentralised", 6, 2, generator=gen)
    b = 64
    obs, actions = torch.randn(b, 6, generator=gen), torch.randint(2, (b,), generator=gen)
    with torch.no_grad():
        old_logp = torch.log_softmax(model.logits(obs), -1).gather(-1, actions[:, None]).squeeze(-1)
    adv, returns = torch.randn(b, generator=gen), torch.randn(b, generator=gen)
    demo = fast_ppo.BehaviourCloning(torch.randn(40, 6, generator=gen), torch.randint(2, (40,), generator=gen),
                                     coef=0.8, half_life=1000.0, start_timesteps=0)
    hp = fast_ppo.PPOArgs(n_epochs=1, minibatch_size=b, max_grad_norm=1e9)

    class Recorder:  # an optimiser that keeps the gradient it is asked to step on
        param_groups = [{"lr": 0.0}]

        def step(self):
            self.grads = [p.grad.clone() for p in model.net.parameters()]

    draws = torch.Generator().manual_seed(5)
    recorder = Recorder()
    fast_ppo.update(model, recorder, hp, draws, obs, actions, old_logp, adv, returns, bc=demo, bc_weight=0.8)
    replay = torch.Generator().manual_seed(5)
    order = torch.randperm(b, generator=replay)
    cloned = torch.randint(40, (b,), generator=replay)
    norm_adv = (adv[order] - adv[order].mean()) / (adv[order].std() + 1e-8)
    ppo, *_ = _autograd_loss(model.logits(obs[order]), model.value(obs[order]), actions[order], old_logp[order],
                             norm_adv, returns[order], hp.clip_range, hp.vf_coef, hp.ent_coef, None)
    bc = torch.nn.functional.cross_entropy(model.logits(demo.obs[cloned]), demo.labels[cloned])
    want = torch.autograd.grad(ppo + 0.8 * bc, list(model.net.parameters()))
    for got, expected in zip(recorder.grads, want):
        torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-6)
    assert any(float(g.abs().max()) > 1e-3 for g in want)
    # at weight 0: PPO's gradient, and the generator where PPO alone leaves it
    alone, with_zero = Recorder(), Recorder()
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    fast_ppo.update(model, alone, hp, g1, obs, actions, old_logp, adv, returns)
    fast_ppo.update(model, with_zero, hp, g2, obs, actions, old_logp, adv, returns, bc=demo, bc_weight=0.0)
    assert all(torch.equal(a, z) for a, z in zip(alone.grads, with_zero.grads))
    assert torch.equal(g1.get_state(), g2.get_state())
    assert demo.weight_at(0) == 0.8 and demo.weight_at(2000) == pytest.approx(0.2)
