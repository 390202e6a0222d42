"""The native PPO's compiled arithmetic (training/ppo_kernel.py) against torch: an update's gradient
is autograd's of SB3's loss, several epochs of it are autograd's with torch's clip and Adam, the
rollout's step samples the softmax and reports its log-probability, the flat Adam reads torch's state."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from containergym_marl.policies.actor_critic import MASKED_LOGIT, ActorCritic
from containergym_marl.training import fast_ppo
from containergym_marl.training.ppo_kernel import FlatAdam, act, blas_threads, parameter_layout


def _autograd_loss(logits, values, actions, old_logp, adv, returns, clip, vf_coef, ent_coef, masks):
    """SB3's PPO loss through autograd."""
    if masks is not None:
        logits = logits.masked_fill(~masks, MASKED_LOGIT)
    log_probs = torch.log_softmax(logits, -1)
    log_ratio = log_probs.gather(-1, actions[:, None]).squeeze(-1) - old_logp
    ratio = log_ratio.exp()
    policy_loss = -torch.min(adv * ratio, adv * torch.clamp(ratio, 1 - clip, 1 + clip)).mean()
    entropy = -(log_probs.exp() * log_probs.clamp_min(torch.finfo(log_probs.dtype).min)).sum(-1).mean()
    return policy_loss + vf_coef * torch.nn.functional.mse_loss(returns, values) - ent_coef * entropy, entropy, ratio, log_ratio


def _rollout(model, b, gen, masked):
    """Samples of ``model``'s policy, a third at ratio 1 (every first epoch), a third within the clip
    range, a third well outside it (either side); masks with the first action always allowed."""
    obs = torch.randn(b, model.observation_size, generator=gen)
    masks = torch.rand(b, model.n_actions, generator=gen) < 0.7 if masked else None
    if masks is not None:
        masks[:, 0] = True
    with torch.no_grad():
        log_probs = torch.log_softmax(model.logits(obs, masks), -1)
    actions = torch.multinomial(log_probs.exp(), 1, generator=gen).squeeze(-1)
    current = log_probs.gather(-1, actions[:, None]).squeeze(-1)
    shift = torch.cat([torch.zeros(b // 3), torch.empty(b // 3).uniform_(-0.1, 0.1, generator=gen),
                       torch.empty(b - 2 * (b // 3)).uniform_(-1.0, 1.0, generator=gen)])
    return obs, actions, current + shift, torch.randn(b, generator=gen), torch.randn(b, generator=gen), masks


@pytest.mark.parametrize("view, obs_size, n_actions, hidden, masked, ent_coef", [
    ("decentralised", 7, 2, (64, 64), False, 0.0),  # a container agent: a narrow first layer
    ("centralised", 33, 12, (64, 64), True, 0.01),  # the controller, with the free-PU mask
    ("decentralised", 5, 2, (16, 32, 8), False, 0.05),  # three hidden layers of different widths
])
def test_the_update_steps_on_autograds_gradient_of_sb3s_loss(view, obs_size, n_actions, hidden, masked, ent_coef):
    """One epoch of one minibatch, the clip out of reach: the gradient the update stepped on (left in
    the flat gradient buffer) is autograd's of the loss at the start, parameter by parameter, and the
    diagnostics are the loss's."""
    gen = torch.Generator().manual_seed(7)
    model = ActorCritic(view, obs_size, n_actions, hidden, generator=gen)
    b, clip = 240, 0.2
    obs, actions, old_logp, adv, returns, masks = _rollout(model, b, gen, masked)
    start = ActorCritic.from_dict(model.to_dict(), "test")
    order = torch.randperm(b, generator=torch.Generator().manual_seed(0))  # the update's one permutation
    norm_adv = (adv[order] - adv[order].mean()) / (adv[order].std() + 1e-8)
    loss, entropy, ratio, log_ratio = _autograd_loss(
        start.logits(obs[order]), start.value(obs[order]), actions[order], old_logp[order], norm_adv, returns[order],
        clip, 0.5, ent_coef, None if masks is None else masks[order])
    want = torch.autograd.grad(loss, list(start.net.parameters()))

    optimizer = FlatAdam(model.net.parameters(), lr=1e-3, eps=1e-5)
    hp = fast_ppo.PPOArgs(n_epochs=1, minibatch_size=b, clip_range=clip, ent_coef=ent_coef, max_grad_norm=1e9)
    got = fast_ppo.update(model, optimizer, hp, torch.Generator().manual_seed(0), obs, actions, old_logp, adv, returns,
                          masks)
    for (name, p), expected in zip(model.net.named_parameters(), want):
        torch.testing.assert_close(p.grad, expected, rtol=1e-4, atol=1e-6, msg=name)
    assert sum(float(g.abs().sum()) for g in want) > 1e-2  # the comparison is of gradients that are there
    entropy, ratio, log_ratio = entropy.detach(), ratio.detach(), log_ratio.detach()
    assert got["entropy"] == pytest.approx(float(entropy), rel=1e-5)
    assert got["approx_kl"] == pytest.approx(float(((ratio - 1) - log_ratio).mean()), rel=1e-4)
    clipped = float(((ratio - 1).abs() > clip).float().mean())
    assert got["clip_fraction"] == pytest.approx(clipped, abs=1e-6) and 0 < clipped < 1
    assert optimizer.steps == 1


@pytest.mark.parametrize("masked", [False, True])
def test_epochs_of_minibatches_follow_autograd_with_torchs_clip_and_adam(masked):
    """Three epochs of three minibatches with the norm clip active: the parameters end where autograd,
    ``clip_grad_norm_`` and ``torch.optim.Adam`` take them from the same start over the same shuffles
    (each epoch's permutation of the same generator, split as ``torch.tensor_split``)."""
    gen = torch.Generator().manual_seed(9)
    n_actions = 4 if masked else 2
    model = ActorCritic("decentralised", 6, n_actions, generator=gen)
    obs, actions, old_logp, adv, returns, masks = _rollout(model, 300, gen, masked)
    reference, start = ActorCritic.from_dict(model.to_dict(), "test"), ActorCritic.from_dict(model.to_dict(), "start")
    hp = fast_ppo.PPOArgs(n_epochs=3, minibatch_size=100, learning_rate=3e-3, ent_coef=0.01, max_grad_norm=0.3)

    optimizer = FlatAdam(model.net.parameters(), lr=hp.learning_rate, eps=hp.adam_eps)
    fast_ppo.update(model, optimizer, hp, torch.Generator().manual_seed(2), obs, actions, old_logp, adv, returns, masks)

    params = list(reference.net.parameters())
    adam = torch.optim.Adam(params, lr=hp.learning_rate, eps=hp.adam_eps)
    draws, norms = torch.Generator().manual_seed(2), []
    for _ in range(hp.n_epochs):
        for idx in torch.tensor_split(torch.randperm(300, generator=draws), 3):
            a = (adv[idx] - adv[idx].mean()) / (adv[idx].std() + 1e-8)
            loss, *_ = _autograd_loss(reference.logits(obs[idx]), reference.value(obs[idx]), actions[idx],
                                      old_logp[idx], a, returns[idx], hp.clip_range, hp.vf_coef, hp.ent_coef,
                                      None if masks is None else masks[idx])
            adam.zero_grad()
            loss.backward()
            norms.append(float(torch.nn.utils.clip_grad_norm_(params, hp.max_grad_norm)))
            adam.step()
    assert max(norms) > hp.max_grad_norm  # the clip acted
    assert optimizer.steps == 9
    for (name, ours), theirs in zip(model.net.named_parameters(), params):
        torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=2e-6, msg=name)
    moved = max(float((a - b).abs().max()) for a, b in zip(model.net.state_dict().values(), start.net.state_dict().values()))
    assert moved > 1e-3  # nine steps of 3e-3: far more than the tolerance


def test_one_update_with_the_behaviour_cloning_term_follows_the_summed_loss():
    """One PPO update (one epoch, one minibatch) with DAPG's term at weight 0.8: the gradient it steps
    on is autograd's of PPO's loss on the rollout plus 0.8 × the cross-entropy on the demonstrations it
    drew (the run's generator: the minibatch order, then the demonstrations), the value network's
    gradient PPO's alone. At weight 0 the update is PPO's, bit for bit, and draws nothing more."""
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

    def gradient(bc_weight, seed=5):
        """The gradient one update of a copy of the model steps on, and its generator afterwards."""
        copy = ActorCritic.from_dict(model.to_dict(), "test")
        optimizer, draws = FlatAdam(copy.net.parameters(), lr=1e-3, eps=1e-5), torch.Generator().manual_seed(seed)
        fast_ppo.update(copy, optimizer, hp, draws, obs, actions, old_logp, adv, returns, bc=demo, bc_weight=bc_weight)
        return optimizer.flat_grad.clone(), draws

    got, _ = gradient(0.8)
    replay = torch.Generator().manual_seed(5)
    order = torch.randperm(b, generator=replay)
    cloned = torch.randint(40, (b,), generator=replay)
    norm_adv = (adv[order] - adv[order].mean()) / (adv[order].std() + 1e-8)
    ppo, *_ = _autograd_loss(model.logits(obs[order]), model.value(obs[order]), actions[order], old_logp[order],
                             norm_adv, returns[order], hp.clip_range, hp.vf_coef, hp.ent_coef, None)
    bc = torch.nn.functional.cross_entropy(model.logits(demo.obs[cloned]), demo.labels[cloned])
    want = torch.cat([g.reshape(-1) for g in torch.autograd.grad(ppo + 0.8 * bc, list(model.net.parameters()),
                                                                 retain_graph=True)])
    torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-6)
    ppo_alone = torch.cat([g.reshape(-1) for g in torch.autograd.grad(ppo, list(model.net.parameters()))])
    assert float((want - ppo_alone).abs().max()) > 1e-3  # the term is there
    # at weight 0: PPO's gradient, and the generator where PPO alone leaves it
    with_zero, draws_with_zero = gradient(0.0)
    copy = ActorCritic.from_dict(model.to_dict(), "test")
    optimizer, draws_alone = FlatAdam(copy.net.parameters(), lr=1e-3, eps=1e-5), torch.Generator().manual_seed(5)
    fast_ppo.update(copy, optimizer, hp, draws_alone, obs, actions, old_logp, adv, returns)
    assert torch.equal(with_zero, optimizer.flat_grad)
    assert torch.equal(draws_with_zero.get_state(), draws_alone.get_state())
    assert demo.weight_at(0) == 0.8 and demo.weight_at(2000) == pytest.approx(0.2)


def test_the_rollout_step_samples_the_softmax_and_reports_its_log_probability():
    """``act``: the action of highest logit + Gumbel noise, its log-probability and the value as the
    model's modules give them (to float rounding: the kernel's own tanh); masked actions never drawn;
    over many uniforms the actions' frequencies are the softmax's (a chi-square bound, fixed seed)."""
    gen = torch.Generator().manual_seed(3)
    model = ActorCritic("centralised", 9, 5, generator=gen)
    with torch.no_grad():  # logits large enough that the softmax is far from uniform
        model.net.actor[-1].weight.mul_(80.0)
    optimizer = FlatAdam(model.net.parameters(), lr=1e-3, eps=1e-5)
    layout, actor_layers = parameter_layout(model, optimizer.flat_param)
    obs = torch.randn(6, 9, generator=gen)
    masks = torch.ones(6, 5, dtype=torch.bool)
    masks[1, 2:] = False
    with torch.no_grad():
        log_probs = torch.log_softmax(model.logits(obs, masks), -1)
        values = model.value(obs)
    counts = np.zeros((6, 5))
    draws = 4000
    for _ in range(draws):
        gumbel = torch.rand(6, 5, generator=gen).log_().neg_().log_()
        actions, logp, vals = np.zeros(6, np.int64), np.zeros(6, np.float32), np.zeros(6, np.float32)
        act(optimizer.flat_param.numpy(), layout, actor_layers, obs.numpy(), gumbel.numpy(), masks.numpy(),
            MASKED_LOGIT, actions, logp, vals)
        want = torch.argmax(log_probs - gumbel, -1)  # Gumbel-max on torch's log-probabilities
        assert np.array_equal(actions, want.numpy())
        np.testing.assert_allclose(logp, log_probs.gather(-1, want[:, None]).squeeze(-1).numpy(), rtol=1e-5, atol=1e-5)
        counts[np.arange(6), actions] += 1
    np.testing.assert_allclose(vals, values.numpy(), rtol=1e-5, atol=1e-5)
    assert counts[1, 2:].sum() == 0
    expected = log_probs.exp().numpy() * draws
    keep = expected > 5  # the chi-square approximation's rule of thumb
    chi2 = float((((counts - expected) ** 2)[keep] / expected[keep]).sum())
    assert chi2 < 60.0  # about 24 degrees of freedom: P(chi2 > 60) < 1e-4
    assert (log_probs.exp() < 0.9).all(dim=-1).sum() >= 3  # rows where the sample is not a foregone conclusion


def test_the_flat_adam_reads_torchs_adam_state():
    """A version-1 checkpoint's ``torch.optim.Adam`` state loads into the flat Adam (moments in
    parameter order, step count, step size), and so does its own; moments of another size are refused."""
    model = ActorCritic("decentralised", 6, 2, (8, 8), generator=torch.Generator().manual_seed(2))
    theirs = torch.optim.Adam(model.net.parameters(), lr=1e-2, eps=1e-5)
    gen = torch.Generator().manual_seed(5)
    for _ in range(3):
        for p in model.net.parameters():
            p.grad = torch.randn(p.shape, generator=gen)
        theirs.step()
    ours = FlatAdam(ActorCritic.from_dict(model.to_dict(), "test").net.parameters(), lr=0.5, eps=1e-5)
    ours.load_state_dict(theirs.state_dict())
    assert (ours.steps, ours.param_groups[0]["lr"]) == (3, 1e-2)
    want = torch.cat([theirs.state[p]["exp_avg_sq"].reshape(-1) for p in model.net.parameters()])
    assert torch.equal(ours.exp_avg_sq, want)
    again = FlatAdam(ActorCritic.from_dict(model.to_dict(), "test").net.parameters(), lr=0.5, eps=1e-5)
    again.load_state_dict(ours.state_dict())
    assert torch.equal(again.exp_avg, ours.exp_avg) and again.steps == 3
    with pytest.raises(ValueError, match="moments"):
        FlatAdam(ActorCritic("decentralised", 6, 2, (4,)).net.parameters(), 1e-3, 1e-5).load_state_dict(ours.state_dict())


def test_a_parameter_outside_the_flat_buffer_and_a_torch_optimiser_are_refused():
    model = ActorCritic("decentralised", 6, 2, generator=torch.Generator().manual_seed(1))
    optimizer = FlatAdam(model.net.parameters(), lr=1e-3, eps=1e-5)
    other = ActorCritic("decentralised", 6, 2)
    with pytest.raises(ValueError, match="FlatAdam"):
        parameter_layout(other, optimizer.flat_param)
    obs = torch.randn(8, 6)
    with pytest.raises(TypeError, match="FlatAdam.*Adam"):
        fast_ppo.update(other, torch.optim.Adam(other.net.parameters()), fast_ppo.PPOArgs(minibatch_size=8, n_epochs=1),
                        torch.Generator(), obs, torch.zeros(8, dtype=torch.long), torch.zeros(8), torch.zeros(8),
                        torch.zeros(8))


def test_blas_threads_are_set_inside_the_block_and_restored_after():
    from containergym_marl.training import ppo_kernel

    with blas_threads(1):
        assert all(c.get_num_threads() == 1 for c in ppo_kernel._BLAS) and ppo_kernel._BLAS
    before = [c.get_num_threads() for c in ppo_kernel._BLAS]
    with blas_threads(2):
        assert all(c.get_num_threads() == 2 for c in ppo_kernel._BLAS)
    assert [c.get_num_threads() for c in ppo_kernel._BLAS] == before


def test_the_kernels_tanh_is_within_4e_7_of_tanh():
    from containergym_marl.training.ppo_kernel import _tanh

    x = np.linspace(-12.0, 12.0, 200_001).astype(np.float32)
    got = np.array([_tanh(v) for v in x[::50]], dtype=np.float64)
    assert np.abs(got - np.tanh(x[::50].astype(np.float64))).max() < 4e-7
    assert _tanh(np.float32(0.0)) == 0.0 and _tanh(np.float32(30.0)) == pytest.approx(1.0, abs=4e-7)
