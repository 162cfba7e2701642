"""The feature density behind the monitor's ``ood`` (issue 36, item 3): exact averages
first, then an exponential one that follows the features; a typical sample scores about
1, a shifted one far more; nothing before the first update."""

from __future__ import annotations

import torch

from testbed.learning.features import RATE, FeatureDensity


def test_a_typical_sample_scores_about_one_and_a_shifted_one_far_more() -> None:
    g = torch.Generator().manual_seed(0)
    density = FeatureDensity(2, 16)
    assert not density.ready
    assert torch.equal(density.score(torch.randn(2, 5, 16, generator=g)), torch.zeros(5))
    scale = torch.linspace(0.5, 3.0, 16)
    for _ in range(40):
        density.update(torch.randn(2, 64, 16, generator=g) * scale)
    typical = density.score(torch.randn(2, 500, 16, generator=g) * scale)
    assert 0.85 < float(typical.mean()) < 1.15
    shifted = torch.randn(2, 500, 16, generator=g) * scale
    shifted[..., 0] += 4.0  # four standard deviations along the narrowest feature
    assert float(density.score(shifted).min()) > float(typical.max()) * 0.8
    assert float(density.score(shifted).mean()) > 1.5 * float(typical.mean())


def test_the_first_updates_average_exactly_then_follow_the_features() -> None:
    density = FeatureDensity(1, 2)
    density.update(torch.full((1, 4, 2), 1.0))
    density.update(torch.full((1, 4, 2), 3.0))
    assert torch.allclose(density.mean, torch.full((1, 2), 2.0))  # (1 + 3) / 2
    for _ in range(int(10 / RATE)):
        density.update(torch.full((1, 4, 2), 10.0))
    assert float(density.mean.min()) > 9.0  # the old features have faded
    again = FeatureDensity(1, 2)
    again.load_state_dict(density.state_dict())
    assert torch.equal(again.mean, density.mean) and int(again.count) == int(density.count)


def test_both_ways_of_running_the_members_give_the_same_features() -> None:
    from testbed.learning.policy import PolicyEnsemble

    torch.manual_seed(0)
    loop = PolicyEnsemble(3, "loop")
    vm = PolicyEnsemble(3, "vmap")
    vm.load_state_dict(loop.state_dict())
    images = torch.randint(0, 256, (5, 64, 64, 3), dtype=torch.uint8)
    with torch.no_grad():
        logits, feats = loop(images, features=True)
        v_logits, v_feats = vm(images, features=True)
        assert feats.shape == (3, 5, 64)
        assert torch.allclose(logits, loop(images))  # the same sums as without features
        assert torch.allclose(v_logits, logits, atol=1e-5)
        assert torch.allclose(v_feats, feats, atol=1e-5)
        assert torch.allclose(vm.trunk_features(images), feats, atol=1e-5)
        assert torch.allclose(loop.trunk_features(images), feats)
